"""The VDA 5050 2.1.0 JSON schemas, shipped as package data with their MIT licence
(``LICENSE.txt`` beside them): a plain install validates messages without ``../shared``."""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path
from typing import Any

#: the standard's topics that have a schema
TOPICS = ("connection", "factsheet", "instantActions", "order", "state", "visualization")


def schema_dir() -> Path:
    """The folder holding ``<topic>.schema`` and ``LICENSE.txt``."""
    return Path(str(resources.files(__name__)))


def load_schema(topic: str) -> dict[str, Any]:
    """The 2.1.0 JSON schema of ``topic`` (one of :data:`TOPICS`)."""
    if topic not in TOPICS:
        raise KeyError(f"{topic!r}: no VDA 5050 schema (topics: {', '.join(TOPICS)})")
    return json.loads((schema_dir() / f"{topic}.schema").read_text(encoding="utf-8"))
