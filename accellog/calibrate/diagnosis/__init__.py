"""Is something missing, which effect, does it transfer: diagnose, cross-validation, held-out and leave-one-session-out evidence, the workbench's choices and ladder."""
