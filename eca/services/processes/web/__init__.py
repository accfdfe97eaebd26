"""The web front-end: the live agent in a browser, over WebRTC (see service.py)."""
