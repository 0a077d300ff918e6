"""Drawing: rendering, interop, the report and the viewers (moved here from the top level and apps/)."""
