"""The shape-abstraction network: an occupancy grid in, ``m`` cuboids out.

``AbstractionNet`` reads a ``(B, 1, R, R, R)`` occupancy grid (the grid convention of
:mod:`primkit`: cell ``(i, j, k)`` along X, Y, Z of [-0.5, 0.5]^3) and predicts, for each of ``m``
part slots, a cuboid and the probability that the cuboid exists.

The cuboid convention (the same everywhere in primkit)::

    half_extents (B, m, 3)  (hx, hy, hz): the cuboid spans [-hx, hx] x [-hy, hy] x [-hz, hz] in its own frame
    quaternions  (B, m, 4)  unit, real part first (w, x, y, z): the cuboid frame -> object frame rotation
    translations (B, m, 3)  the cuboid's centre in the object frame
    existence    (B, m)     probability that the part exists (the "cuboid" choice of a cuboid / null pair)

    a point p' of the untransformed cuboid lands at  p = R(q) p' + t  (R(q) acting on column vectors).

Encoder
-------
Two encoders are offered; ``NetworkConfig.encoder`` picks one.

``"released"`` (default): ``log2(R)`` blocks of [3x3x3 conv (padding 1), batch norm, LeakyReLU(0.2),
2x2x2 max-pool] with 4, 8, 16, 32, 64 (, 128 ...) channels, taking R^3 down to 1^3, then two fully
connected layers of ``fc_width`` (64) units with batch norm and LeakyReLU(0.2); every weight drawn
from N(0, 0.02). This is the network the authors' released code trains, so it is the network the
published numbers come from. Batch norm also matters in practice: the input is a grid of 0s and 1s
(mostly 0s) whose statistics vary a lot between shapes and categories, and normalising every
layer's activations makes training insensitive to that, and to the small N(0, 0.02) initial
weights, which without normalisation would shrink the signal by about 5x per layer.

``"paper"``: the variant of the paper's appendix (A3): ``log2(R)`` 3x3x3 convolutions of stride 2
(padding 1) with ReLU, the same channel counts, then two fully connected layers with ReLU; the
appendix uses 100 units (``NetworkConfig.paper()`` sets ``fc_width=100``). It has no batch norm,
so its trunk is initialised with He (Kaiming) normal weights rather than N(0, 0.02), which would
make the features vanish; the heads are initialised as in the released variant.

Heads
-----
One ``Linear`` layer per quantity, shared by all parts; its ``m * k`` outputs are read as
``(m, k)``, part-major: output unit ``part * k + component`` is component ``component`` of part
``part`` (``Tensor.unflatten(1, (m, k))``)::

    half_extents = max_half_extent * sigmoid(shape_scale * (W_z h + b_z))       k = 3
    quaternions  = normalise(shape_scale * (W_q h + b_q))                       k = 4
    translations = 0.5 * tanh(shape_scale * (W_t h + b_t))                     k = 3
    existence    = sigmoid(existence_scale * (W_p h + b_p))                     k = 1

The existence sigmoid is the two-way softmax over {cuboid, null} of the paper written with one
logit, ``p(cuboid) = sigmoid(l_cuboid - l_null)``.

Initialisation: ``b_z`` is set so every part starts as a small cube of half-extent
``INITIAL_HALF_EXTENT`` = 0.024 (the released code's bias of about -3 through the sigmoid, i.e.
0.5 * sigmoid(-2.99) = 0.024: a cube of side 0.048, about 1.5 cells of a 32^3 grid); ``b_q`` is
(1, 0, 0, 0) with weights 10x smaller than elsewhere (N(0, 0.002)) so every part starts close to
the identity rotation (a few degrees off); ``b_t`` is 0, so parts start near the centre with a small
random spread from the N(0, 0.02) weights; ``b_p`` is set so ``p`` starts at ``INITIAL_EXISTENCE``
= 0.92, every part used at first.

Head scaling
------------
``shape_scale`` multiplies the pre-activations of the three shape heads and ``existence_scale`` that
of the existence head. With Adam (whose steps are about the learning rate whatever the gradient's
size), a head whose output is ``s * (W h + b)`` moves ``s`` times slower, which is how the two
training stages slow the shape heads and freeze the existence head. ``set_head_scales`` changes the
scales while dividing the heads' weights and biases by ``new / old``, so the network computes
exactly the same function before and after the switch (as the released code does between stages).
The scales are buffers (``head_scales`` in the state dict): the weights are only meaningful with the
scales they were trained under, so the two are saved and loaded together.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from .modelfile import ModelFileError, check_tensors, load_model_file, read_header

#: Tensors of a model file that are not the network's: the part labeller's
#: (:mod:`primkit.segmentation.labeller`, which reads and checks them itself).
AUXILIARY_PREFIXES = ("labeller.",)

__all__ = [
    "INITIAL_EXISTENCE",
    "INITIAL_HALF_EXTENT",
    "MAX_NETWORK_PARTS",
    "MAX_NETWORK_GRID",
    "MAX_FC_WIDTH",
    "AbstractionNet",
    "NetworkConfig",
    "PrimitivePrediction",
    "abstraction_net_state_shapes",
    "read_network",
    "load_network",
]

#: Half-extent of every part at initialisation (the released code's starting size).
INITIAL_HALF_EXTENT = 0.024
#: Existence probability of every part at initialisation (the paper: "p_m = 0.9").
INITIAL_EXISTENCE = 0.92
#: Standard deviation of the initial weights (released code), and of the quaternion head's weights.
WEIGHT_STD = 0.02
QUATERNION_WEIGHT_STD = 0.002
#: Slope of the LeakyReLU of the released encoder.
LEAKY_SLOPE = 0.2

_ENCODERS = ("released", "paper")

#: Bounds of the architecture's fields: far above any use (the paper: 20 parts, 32^3, 100 units),
#: far below what would exhaust memory (a 256^3 grid of batch 32 is 2 GB of input alone).
MAX_NETWORK_PARTS = 1024
MAX_NETWORK_GRID = 256
MAX_FC_WIDTH = 8192


@dataclass(frozen=True)
class NetworkConfig:
    """Everything needed to rebuild an ``AbstractionNet`` (saved in model files as ``to_dict()``).

    parts : number of part slots ``m``.
    grid : input resolution ``R``, a power of two >= 4; the encoder has ``log2(R)`` blocks.
    encoder : ``"released"`` (conv + batch norm + max-pool, as the authors' code) or ``"paper"``
        (stride-2 convs + ReLU, as the paper's appendix).
    fc_width : units of each of the two fully connected layers (released: 64, paper: 100).
    max_half_extent : the largest half-extent a part can take (0.5: a part can span the whole cube).
    """

    parts: int = 20
    grid: int = 32
    encoder: str = "released"
    fc_width: int = 64
    max_half_extent: float = 0.5

    def __post_init__(self) -> None:
        if not isinstance(self.parts, int) or isinstance(self.parts, bool) or not 1 <= self.parts <= MAX_NETWORK_PARTS:
            raise ValueError(f"`parts` must be an int from 1 to {MAX_NETWORK_PARTS}, got {self.parts!r}")
        grid = self.grid
        if (
            not isinstance(grid, int)
            or isinstance(grid, bool)
            or not 4 <= grid <= MAX_NETWORK_GRID
            or grid & (grid - 1) != 0
        ):
            raise ValueError(f"`grid` must be a power of two from 4 to {MAX_NETWORK_GRID} (e.g. 32 or 64), got {grid!r}")
        if not isinstance(self.encoder, str) or self.encoder not in _ENCODERS:
            raise ValueError(f"`encoder` must be one of {_ENCODERS}, got {self.encoder!r}")
        if not isinstance(self.fc_width, int) or isinstance(self.fc_width, bool) or not 1 <= self.fc_width <= MAX_FC_WIDTH:
            raise ValueError(f"`fc_width` must be an int from 1 to {MAX_FC_WIDTH}, got {self.fc_width!r}")
        if not (isinstance(self.max_half_extent, (int, float)) and not isinstance(self.max_half_extent, bool)
                and math.isfinite(self.max_half_extent) and self.max_half_extent > 0):
            raise ValueError(f"`max_half_extent` must be a finite number > 0, got {self.max_half_extent!r}")
        if INITIAL_HALF_EXTENT >= self.max_half_extent:
            raise ValueError(
                f"`max_half_extent` must exceed the initial half-extent {INITIAL_HALF_EXTENT}, "
                f"got {self.max_half_extent!r}"
            )

    @classmethod
    def paper(cls, parts: int = 20, grid: int = 32) -> "NetworkConfig":
        """The paper's appendix architecture: stride-2 convolutions, fully connected layers of 100."""
        return cls(parts=parts, grid=grid, encoder="paper", fc_width=100)

    @property
    def blocks(self) -> int:
        """Number of encoder blocks, ``log2(grid)`` (each halves the resolution)."""
        return self.grid.bit_length() - 1

    def to_dict(self) -> dict:
        """Plain JSON-serialisable dict of the fields."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "NetworkConfig":
        """Inverse of ``to_dict``; missing keys take their defaults, unknown keys are an error."""
        if not isinstance(d, dict):
            raise ValueError(f"network config must be a dict, got {type(d).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"unknown network config keys {unknown}; known: {sorted(known)}")
        return cls(**d)


@dataclass
class PrimitivePrediction:
    """The network's output for a batch (torch tensors; see the module docstring for conventions).

    half_extents : (B, m, 3) float, in (0, max_half_extent).
    quaternions : (B, m, 4) float, unit, real part first (w, x, y, z).
    translations : (B, m, 3) float, in (-0.5, 0.5).
    existence : (B, m) float, probabilities in (0, 1).
    existence_logits : (B, m) float, the scaled logit with ``existence = sigmoid(existence_logits)``;
        use ``F.logsigmoid(l)`` and ``F.logsigmoid(-l)`` for stable log-probabilities of the cuboid
        and null choices. ``None`` when the prediction was not made by the network.
    """

    half_extents: Tensor
    quaternions: Tensor
    translations: Tensor
    existence: Tensor
    existence_logits: Tensor | None = None

    @property
    def parts(self) -> int:
        """Number of part slots ``m``."""
        return self.existence.shape[-1]

    def detach(self) -> "PrimitivePrediction":
        """A copy cut from the autograd graph."""
        return PrimitivePrediction(
            *(None if t is None else t.detach() for t in self._tensors())
        )

    def to(self, *args, **kwargs) -> "PrimitivePrediction":
        """``Tensor.to`` applied to every field."""
        return PrimitivePrediction(
            *(None if t is None else t.to(*args, **kwargs) for t in self._tensors())
        )

    def _tensors(self) -> tuple:
        return (
            self.half_extents,
            self.quaternions,
            self.translations,
            self.existence,
            self.existence_logits,
        )


def _logit(p: float) -> float:
    return math.log(p / (1.0 - p))


class AbstractionNet(nn.Module):
    """3D CNN from an occupancy grid to ``m`` cuboids with existence probabilities.

    Batch norm (released encoder) needs batches of at least 2 in training mode; use ``eval()`` for
    prediction. See the module docstring for the architecture, heads, initialisation and scaling.
    """

    def __init__(self, config: NetworkConfig = NetworkConfig()) -> None:
        super().__init__()
        if not isinstance(config, NetworkConfig):
            raise TypeError(f"`config` must be a NetworkConfig, got {type(config).__name__}")
        self.config = config
        m, width = config.parts, config.fc_width
        channels = [1] + [4 * 2**b for b in range(config.blocks)]

        layers: list[nn.Module] = []
        if config.encoder == "released":
            for c_in, c_out in zip(channels[:-1], channels[1:]):
                layers += [
                    nn.Conv3d(c_in, c_out, kernel_size=3, padding=1, bias=False),
                    nn.BatchNorm3d(c_out),
                    nn.LeakyReLU(LEAKY_SLOPE),
                    nn.MaxPool3d(2),
                ]
            layers.append(nn.Flatten())  # (B, C, 1, 1, 1) -> (B, C)
            layers += [
                nn.Linear(channels[-1], width, bias=False),
                nn.BatchNorm1d(width),
                nn.LeakyReLU(LEAKY_SLOPE),
                nn.Linear(width, width, bias=False),
                nn.BatchNorm1d(width),
                nn.LeakyReLU(LEAKY_SLOPE),
            ]
        else:  # "paper"
            for c_in, c_out in zip(channels[:-1], channels[1:]):
                layers += [nn.Conv3d(c_in, c_out, kernel_size=3, stride=2, padding=1), nn.ReLU()]
            layers.append(nn.Flatten())
            layers += [nn.Linear(channels[-1], width), nn.ReLU(), nn.Linear(width, width), nn.ReLU()]
        self.encoder = nn.Sequential(*layers)

        self.half_extent_head = nn.Linear(width, m * 3)
        self.quaternion_head = nn.Linear(width, m * 4)
        self.translation_head = nn.Linear(width, m * 3)
        self.existence_head = nn.Linear(width, m)
        # (shape_scale, existence_scale); float64 so that repeated rescaling stays exact enough.
        self.register_buffer("head_scales", torch.ones(2, dtype=torch.float64))
        self.reset_parameters()

    # ------------------------------------------------------------------ initialisation
    def reset_parameters(self) -> None:
        """Initialise every weight as described in the module docstring (head scales set to 1)."""
        if self.head_scales.is_meta:
            # a network built for its shapes only (abstraction_net_state_shapes): nothing to draw, and
            # torch's meta-device normal_ imports torch._dynamo, 1.5-3 s of every command's start
            return
        released = self.config.encoder == "released"
        for module in self.encoder.modules():
            if isinstance(module, (nn.Conv3d, nn.Linear)):
                if released:
                    nn.init.normal_(module.weight, 0.0, WEIGHT_STD)
                else:
                    nn.init.kaiming_normal_(module.weight, nonlinearity="relu")
                if module.bias is not None:
                    nn.init.zeros_(module.bias)
            elif isinstance(module, (nn.BatchNorm1d, nn.BatchNorm3d)):
                module.reset_parameters()
        with torch.no_grad():
            self.head_scales.fill_(1.0)
            nn.init.normal_(self.half_extent_head.weight, 0.0, WEIGHT_STD)
            self.half_extent_head.bias.fill_(
                _logit(INITIAL_HALF_EXTENT / self.config.max_half_extent)
            )
            nn.init.normal_(self.quaternion_head.weight, 0.0, QUATERNION_WEIGHT_STD)
            quaternion_bias = self.quaternion_head.bias.view(self.config.parts, 4)
            quaternion_bias.zero_()
            quaternion_bias[:, 0] = 1.0
            nn.init.normal_(self.translation_head.weight, 0.0, WEIGHT_STD)
            self.translation_head.bias.zero_()
            nn.init.normal_(self.existence_head.weight, 0.0, WEIGHT_STD)
            self.existence_head.bias.fill_(_logit(INITIAL_EXISTENCE))

    # ------------------------------------------------------------------ head scaling
    @property
    def shape_scale(self) -> float:
        """Multiplier of the shape heads' (z, q, t) pre-activations; change with ``set_head_scales``."""
        return float(self.head_scales[0])

    @property
    def existence_scale(self) -> float:
        """Multiplier of the existence head's pre-activation; change with ``set_head_scales``."""
        return float(self.head_scales[1])

    def set_head_scales(
        self, shape_scale: float, existence_scale: float, *, preserve_function: bool = True
    ) -> None:
        """Set the head scales; by default rescale the heads so the outputs do not change.

        With ``preserve_function`` the weights and biases of the shape heads are multiplied by
        ``old_shape_scale / shape_scale`` (and those of the existence head likewise), so
        ``scale * (W h + b)`` is the same before and after. With ``preserve_function=False`` only
        the scales change (the function changes too).
        """
        for name, value in (("shape_scale", shape_scale), ("existence_scale", existence_scale)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"`{name}` must be a finite number > 0, got {value!r}")
        old_shape, old_existence = self.shape_scale, self.existence_scale
        with torch.no_grad():
            if preserve_function:
                for head in (self.half_extent_head, self.quaternion_head, self.translation_head):
                    head.weight.mul_(old_shape / shape_scale)
                    head.bias.mul_(old_shape / shape_scale)
                self.existence_head.weight.mul_(old_existence / existence_scale)
                self.existence_head.bias.mul_(old_existence / existence_scale)
            self.head_scales[0] = float(shape_scale)
            self.head_scales[1] = float(existence_scale)

    # ------------------------------------------------------------------ forward
    def forward(self, occupancy: Tensor) -> PrimitivePrediction:
        """Predict the cuboids of a batch of occupancy grids.

        occupancy : (B, 1, R, R, R) or (B, R, R, R), float or bool (1 = inside), ``R = config.grid``.
        Returns a ``PrimitivePrediction`` whose tensors have batch size ``B`` and ``m = config.parts``.
        """
        occupancy = torch.as_tensor(occupancy)
        r = self.config.grid
        if occupancy.dim() == 4:
            occupancy = occupancy.unsqueeze(1)
        if occupancy.dim() != 5 or tuple(occupancy.shape[1:]) != (1, r, r, r):
            raise ValueError(
                f"`occupancy` must be (B, 1, {r}, {r}, {r}) or (B, {r}, {r}, {r}), "
                f"got {tuple(occupancy.shape)}"
            )
        weight = self.half_extent_head.weight
        occupancy = occupancy.to(device=weight.device, dtype=weight.dtype)

        h = self.encoder(occupancy)  # (B, fc_width)
        m = self.config.parts
        shape_scale = self.head_scales[0].to(h.dtype)
        existence_scale = self.head_scales[1].to(h.dtype)

        z_pre = shape_scale * self.half_extent_head(h).unflatten(1, (m, 3))
        q_pre = shape_scale * self.quaternion_head(h).unflatten(1, (m, 4))
        t_pre = shape_scale * self.translation_head(h).unflatten(1, (m, 3))
        p_logit = existence_scale * self.existence_head(h)  # (B, m)

        return PrimitivePrediction(
            half_extents=self.config.max_half_extent * torch.sigmoid(z_pre),
            quaternions=F.normalize(q_pre, dim=-1, eps=1e-12),
            translations=0.5 * torch.tanh(t_pre),
            existence=torch.sigmoid(p_logit),
            existence_logits=p_logit,
        )

    def extra_repr(self) -> str:
        return (
            f"parts={self.config.parts}, grid={self.config.grid}, encoder={self.config.encoder!r}, "
            f"shape_scale={self.shape_scale:g}, existence_scale={self.existence_scale:g}"
        )


def abstraction_net_state_shapes(config: NetworkConfig) -> dict[str, tuple[tuple[int, ...], torch.dtype]]:
    """``name -> (shape, dtype)`` of the state dict of ``AbstractionNet(config)``, from a network
    built on torch's ``meta`` device (no memory is allocated, whatever the config)."""
    with torch.device("meta"):
        net = AbstractionNet(config)
    return {k: (tuple(v.shape), v.dtype) for k, v in net.state_dict().items()}


def read_network(path) -> tuple[NetworkConfig, dict]:
    """The network config and metadata of a model file (or a training checkpoint), validated
    against its header before any weight is read or any network built.

    Checks: the ``network`` fields (types and bounds, :class:`NetworkConfig`), ``grid`` and
    ``part_names`` when present, and the tensors the architecture implies against those in the
    header (names, shapes, dtypes; a checkpoint's ``model.*`` tensors). Raises
    :class:`~primkit.model.modelfile.ModelFileError`, one line naming the file.
    """
    meta, tensors = read_header(path)
    try:
        config = NetworkConfig.from_dict(meta["network"])
    except (TypeError, ValueError) as exc:
        raise ModelFileError(path, f"bad network description in the metadata: {exc}") from None
    if "grid" in meta and meta["grid"] != config.grid:
        raise ModelFileError(path, f"metadata grid {meta['grid']!r} differs from the network's {config.grid}")
    names = meta.get("part_names")
    if names is not None and not (isinstance(names, list) and len(names) == config.parts
                                  and all(isinstance(n, str) for n in names)):
        raise ModelFileError(path, f"part_names must be a list of {config.parts} strings (one per part slot)")
    tensors = {k: v for k, v in tensors.items() if not k.startswith(AUXILIARY_PREFIXES)}  # a labeller's, checked there
    model = {k[len("model."):]: v for k, v in tensors.items() if k.startswith("model.")}
    check_tensors(path, abstraction_net_state_shapes(config), model or tensors)  # a checkpoint's optimizer and rng tensors aside
    return config, meta


def load_network(path, map_location="cpu") -> tuple[AbstractionNet, dict]:
    """Network and metadata from a model file (or a checkpoint) written by :func:`primkit.model.training.train`,
    validated (:func:`read_network`) before anything is allocated."""
    config, _ = read_network(path)
    weights, meta = load_model_file(path, map_location=map_location)
    net = AbstractionNet(config)
    weights = {k: v for k, v in weights.items() if not k.startswith(AUXILIARY_PREFIXES)}
    state = {k[len("model."):]: v for k, v in weights.items() if k.startswith("model.")} or weights
    net.load_state_dict(state)
    net.eval()
    return net, meta
