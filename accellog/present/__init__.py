"""present: terminal/markdown tables, Rerun recordings (.rrd, live views, blueprints) and the viewer. Imports every layer below, never flows or cli."""
