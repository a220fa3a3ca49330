"""Deterministic nuScenes tokens: re-running a conversion must give byte-identical tables.

A token is the first 32 hex digits of SHA-256 over the JSON list ``[scope, table, key]``
(JSON quoting keeps the three parts apart whatever characters they hold). ``scope`` is the
source log id for per-log records and ``""`` for the shared vocabularies (category, attribute,
sensor), so two logs never share a per-log token and every log agrees on a category token.
"""

from __future__ import annotations

import hashlib
import json
import re

TOKEN_RE = re.compile(r"^[0-9a-f]{32}$")
GLOBAL_SCOPE = ""


def make_token(scope: str, table: str, key: str) -> str:
    """32 lowercase hex characters identifying record ``key`` of ``table`` within ``scope``."""
    digest = hashlib.sha256(json.dumps([scope, table, key]).encode()).hexdigest()
    return digest[:32]


def global_token(table: str, key: str) -> str:
    """Token of a record shared by all logs (category, attribute, sensor)."""
    return make_token(GLOBAL_SCOPE, table, key)


def is_token(value: object) -> bool:
    return isinstance(value, str) and bool(TOKEN_RE.match(value))
