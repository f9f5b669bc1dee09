"""Rerun recordings: entity names (entities), sinks and viewer processes (sinks), RunRecording (recording), blueprints (layout), the live view (live)."""
