"""The formats ``accellog export --to`` writes and their file suffixes: a module of names only, so
that the command line offers them (choices, shell completion) without importing numpy."""

TARGETS = ("kalibr", "ros", "px4", "ardupilot", "yaml")
SUFFIX = {"kalibr": ".yaml", "ros": ".yaml", "px4": ".params", "ardupilot": ".parm", "yaml": ".yaml"}
