"""The HTTP/WebSocket service front door (``agv-mission serve``)."""
