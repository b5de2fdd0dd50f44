"""Sub-commands of the `planar-pose` CLI, one module per pipeline step."""
