"""API tokens: random secrets shown once, stored as sha256 hashes; and keeping them out of logs."""

from __future__ import annotations

import hashlib
import logging
import re
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


# A token in a query string (``?token=…``, ``&access_token=…``) or a bare cornerman token anywhere.
_QUERY_SECRET = re.compile(r"(?i)\b((?:access_)?token|ticket)=[^&\s\"']+")
_BARE_TOKEN = re.compile(r"cm_[A-Za-z0-9_-]{8,}")


def redact(text: str) -> str:
    """``text`` with every query-string token and every ``cm_…`` token replaced by ``***``."""
    return _BARE_TOKEN.sub("cm_***", _QUERY_SECRET.sub(r"\1=***", text))


class RedactTokens(logging.Filter):
    """A logging filter that rewrites each record's message with ``redact`` (it never drops one)."""

    def filter(self, record: logging.LogRecord) -> bool:
        # Redact the arguments one by one: uvicorn's access formatter unpacks ``record.args``.
        if isinstance(record.msg, str):
            record.msg = redact(record.msg)
        if isinstance(record.args, tuple):
            record.args = tuple(redact(a) if isinstance(a, str) else a for a in record.args)
        elif isinstance(record.args, dict):
            record.args = {k: redact(v) if isinstance(v, str) else v for k, v in record.args.items()}
        return True


REDACTED_LOGGERS: tuple[str, ...] = ("uvicorn.access", "uvicorn.error", "uvicorn", "server", "webui")
"""Loggers whose records pass through ``RedactTokens`` once ``install_log_redaction()`` ran."""


def install_log_redaction() -> None:
    """Add ``RedactTokens`` to ``REDACTED_LOGGERS`` (idempotent). A filter on a logger sees the records
    logged to that logger itself, which is how uvicorn writes its access log."""
    for name in REDACTED_LOGGERS:
        logger = logging.getLogger(name)
        if not any(isinstance(f, RedactTokens) for f in logger.filters):
            logger.addFilter(RedactTokens())
