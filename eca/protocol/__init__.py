"""The wire contract of eca: message types, the msgpack codec, topics, endpoints and the client."""
