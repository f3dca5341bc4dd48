"""Program and module names every controller language accepts, derived from a file name.

KRL wants an identifier of at most 24 characters (and its ``.src`` / ``.dat``
files named the same), URScript a Python-like identifier, RAPID an identifier
of at most 32 characters (16 on older RobotWare); none of them takes a hyphen,
a blank, a leading digit or a keyword. :func:`program_name` makes one name
that suits them all: other characters become ``_``, a name not starting with a
letter gets ``p_`` in front, a keyword gets ``_prog`` behind, the result is cut
to ``MAX_NAME_CHARS``.
"""
from __future__ import annotations

import re
import unicodedata

__all__ = ["program_name", "MAX_NAME_CHARS", "DEFAULT_NAME"]

MAX_NAME_CHARS = 24          # KRL's limit, the tightest
DEFAULT_NAME = "am_print"
# words no language of ours lets a program or module be called (compared in lower case)
_RESERVED = frozenset("""
    and as assert break case class const continue def default defdat deffct else elseif end enddat endfct
    endfor endif endloop endwhile endswitch exit false for from global goto halt if import in int interrupt
    is lambda loop module none not or pass proc real repeat return signal switch then to true until wait
    while with char bool frame pos e6pos axis e6axis struct enum decl main
""".split())


def program_name(text: str, max_chars: int = MAX_NAME_CHARS) -> str:
    """A name valid in KRL, URScript and RAPID derived from ``text`` (e.g. a file's stem): ``my-part 2``
    becomes ``my_part_2``, ``3dbenchy`` ``p_3dbenchy``, ``end`` ``end_prog``; the same text gives the same name."""
    ascii_text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode("ascii")
    name = re.sub(r"[^A-Za-z0-9]+", "_", ascii_text).strip("_")
    if not name:
        return DEFAULT_NAME
    if not name[0].isalpha():
        name = "p_" + name
    name = name[:max_chars].rstrip("_")
    if name.lower() in _RESERVED:
        name = name[:max_chars - 5] + "_prog"
    return name
