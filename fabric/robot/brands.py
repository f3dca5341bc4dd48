"""Robot makers: the program language each one's controllers run (a cell's ``[robot] brand``).

Declared here, apart from the cell model, so that the thin client (no Pinocchio) reads the same table.
"""
from __future__ import annotations

__all__ = ["NATIVE_EXPORTS", "MAKERS", "language_maker"]

# robot brand ([robot] brand) -> the export its controller runs; a cell naming no brand exports CSV
NATIVE_EXPORTS: dict[str, str] = {"abb": "rapid", "kuka": "krl", "ur": "urscript", "franka": "csv", "": "csv"}
MAKERS: dict[str, str] = {"abb": "ABB", "kuka": "KUKA", "ur": "Universal Robots", "franka": "Franka"}


def language_maker(fmt: str) -> str | None:
    """Whose controllers run export ``fmt`` (``"ABB"`` for rapid); None for CSV, which is anyone's."""
    return next((MAKERS[b] for b, lang in NATIVE_EXPORTS.items() if lang == fmt and fmt != "csv"), None)
