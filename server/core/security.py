"""API tokens: random secrets shown once, stored as sha256 hashes."""

from __future__ import annotations

import hashlib
import secrets
from typing import Literal

Role = Literal["coach", "annotator", "admin"]
ROLES: tuple[str, ...] = ("coach", "annotator", "admin")
ROLE_RANK: dict[str, int] = {"coach": 0, "annotator": 1, "admin": 2}


def new_token() -> str:
    return "cm_" + secrets.token_urlsafe(24)


def hash_token(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


def role_at_least(role: str, needed: str) -> bool:
    if role not in ROLE_RANK or needed not in ROLE_RANK:
        raise ValueError(f"unknown role {role!r} or {needed!r}; known: {ROLES}")
    return ROLE_RANK[role] >= ROLE_RANK[needed]
