"""flows: what a command does end to end: simulate, pipelines, the workbench loop, replay and the demo. Imports every layer below, never cli."""
