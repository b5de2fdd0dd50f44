"""The live stream: `WS /v1/stream`'s protocol (`protocol.py`) and its route (`route.py`)."""
