"""The eca processes: thin loops from the bus into agent/ models and back, the supervisor and the CLI."""
