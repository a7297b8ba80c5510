"""Zenoh access control and authentication for navd's sessions (docs/daemon.md, "Zenoh
threat model").  Plain dicts in the shape of eclipse-zenoh 1.x's ``access_control`` and
``transport/auth/usrpwd`` config sections (checked against the installed version by
tests/test_zenoh_security.py).

Two ACLs:

publisher (navd's own session)
    default allow, with deny rules for what no remote peer needs from navd: ``put``,
    ``delete`` and ``reply`` arriving from outside (navd subscribes to nothing, so nothing
    may be injected through it), and queries on the admin space ``@/**``.  Egress is left
    open so other outputs on the same session (ROS 2 keys, liveliness tokens) keep working.

consumer (a process that subscribes to navd)
    ``put``/``delete`` on ``navd/<vehicle>/**`` arriving from any authenticated user other
    than navd's is denied.  Subjects are usernames, so this is only as strong as the
    authentication: the consumer's listen endpoints must require ``usrpwd`` (a
    ``users_file``) so that no unauthenticated peer can connect at all.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["consumer_acl", "publisher_acl", "read_password", "read_usernames", "usrpwd"]

_INBOUND_DATA = ["put", "delete", "reply"]


def publisher_acl() -> dict[str, Any]:
    """navd's session: refuse data pushed in, and admin-space queries."""
    return {
        "enabled": True,
        "default_permission": "allow",
        "rules": [
            {"id": "no_inbound_data", "permission": "deny", "flows": ["ingress"],
             "messages": _INBOUND_DATA, "key_exprs": ["**"]},
            {"id": "no_admin_space", "permission": "deny", "flows": ["ingress"],
             "messages": ["query"], "key_exprs": ["@/**"]},
        ],
        "subjects": [{"id": "anyone"}],
        "policies": [{"rules": ["no_inbound_data", "no_admin_space"],
                      "subjects": ["anyone"]}],
    }


def consumer_acl(vehicle: str, publisher_user: str, usernames: list[str]) -> dict[str, Any]:
    """A subscriber's session: only ``publisher_user`` may put on ``navd/<vehicle>/**``.

    ``usernames``: every user that can authenticate to this session (its users file); all
    but ``publisher_user`` are denied.  An empty list leaves nothing to deny, so it is
    refused: without authentication the ACL could not tell navd from anyone else.
    """
    others = sorted(set(usernames) - {publisher_user})
    if publisher_user not in usernames:
        raise ValueError(f"the users file has no entry for navd's user {publisher_user!r}")
    # Subjects are named users only: an ACL that also had a subject matching anyone let
    # the intruder's put through in eclipse-zenoh 1.10.2 (measured); with authentication
    # required, the users file lists every peer there can be anyway.
    rules: list[dict[str, Any]] = [
        {"id": "only_navd_publishes", "permission": "deny", "flows": ["ingress"],
         "messages": ["put", "delete"], "key_exprs": [f"navd/{vehicle}/**"]},
        {"id": "no_admin_space", "permission": "deny", "flows": ["ingress"],
         "messages": ["query"], "key_exprs": ["@/**"]},
    ]
    subjects: list[dict[str, Any]] = [{"id": "users", "usernames": sorted(set(usernames))}]
    policies: list[dict[str, Any]] = [{"rules": ["no_admin_space"], "subjects": ["users"]}]
    if others:
        subjects.append({"id": "not_navd", "usernames": others})
        policies.append({"rules": ["only_navd_publishes"], "subjects": ["not_navd"]})
    return {"enabled": True, "default_permission": "allow", "rules": rules,
            "subjects": subjects, "policies": policies}


def usrpwd(user: str, password: str, users_file: str) -> dict[str, Any]:
    """``transport/auth/usrpwd``: the credentials this session presents when it connects
    (``user``/``password``) and the ones it accepts on its listen endpoints
    (``users_file``: ``user:password`` lines).  Empty strings are left out."""
    out: dict[str, Any] = {}
    if user:
        out["user"] = user
        out["password"] = password
    if users_file:
        out["dictionary_file"] = users_file
    return out


def read_usernames(users_file: str | Path) -> list[str]:
    """The users of a zenoh usrpwd dictionary file (``user:password`` per line)."""
    names = []
    for line in Path(users_file).read_text().splitlines():
        if line.strip() and ":" in line:
            names.append(line.split(":", 1)[0].strip())
    if not names:
        raise ValueError(f"{users_file}: no user:password lines")
    return names


def read_password(path: str | Path) -> str:
    """A password kept in its own file (first line), so that it is not in navd.toml, which
    is copied into every recording."""
    text = Path(path).read_text().splitlines()
    if not text or not text[0].strip():
        raise ValueError(f"{path}: empty password file")
    return text[0].strip()
