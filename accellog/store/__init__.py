"""store: the MCAP wire format (protobuf schema and codec), session writer and readers, and importers of other loggers' files. Imports core."""
