"""ROS 2 names: validation and resolution (no Zenoh, no serialiser: the config uses these)."""

from __future__ import annotations

import re

__all__ = ["fully_qualified", "validate_name", "validate_namespace"]

_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


def validate_name(name: str) -> str | None:
    """Why ``name`` is not a valid ROS 2 node name or topic token, or None."""
    if not _NAME.match(name):
        return f"{name!r} is not a ROS name (letters, digits, _; not starting with a digit)"
    return None


def validate_namespace(ns: str) -> str | None:
    """Why ``ns`` is not an absolute ROS 2 namespace ("/" or "/a/b"), or None."""
    if ns == "/":
        return None
    if not ns.startswith("/") or ns.endswith("/"):
        return f"namespace {ns!r} must be '/' or start with '/' and not end with '/'"
    for tok in ns[1:].split("/"):
        err = validate_name(tok)
        if err is not None:
            return f"namespace {ns!r}: {err}"
    return None


def fully_qualified(namespace: str, topic: str) -> str:
    """A relative topic name under ``namespace``; an absolute one (``/x``) as it is."""
    if topic.startswith("/"):
        return topic
    return f"/{topic}" if namespace == "/" else f"{namespace}/{topic}"
