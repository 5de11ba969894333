"""One line of `mamma-kit doctor`: what was checked, whether it is fine, and the fix when not."""

from __future__ import annotations


def check(name: str, ok: bool, detail: str, fix: str = "", optional: bool = False) -> dict:
    d = {"name": name, "ok": bool(ok), "detail": detail}
    if optional:
        d["optional"] = True
    if fix and not ok:
        d["fix"] = fix
    return d
