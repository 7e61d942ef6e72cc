"""Text from a spec (file names, names, descriptions) made safe for generated code.

A spec may come from anyone, and so may the name of its file: nothing of it reaches generated
text except as data. String literals are always printed as JSON/``repr`` (``tojson``);
comments and docstrings — which no quoting protects — only ever receive
:func:`comment_text`, which keeps a short whitelist of printable ASCII characters that can
close neither a Python docstring (quotes, backslashes, newlines) nor a C comment (``*/``).
"""

from __future__ import annotations

import re

_UNSAFE = re.compile(r"[^A-Za-z0-9 _.,:;()\[\]{}<>=+\-/@#%&!?'|^~$]")
_LIMIT = 120


def comment_text(value: object, limit: int = _LIMIT) -> str:
    """``value`` as text safe inside a generated comment or docstring of any target
    (Python, C): characters outside a printable-ASCII whitelist become ``?``, and the text
    is cut to ``limit`` characters.

    Examples
    --------
    >>> comment_text("x" + '"' * 3 + chr(10) + "import os" + chr(10) + '"' * 3 + ".yaml")
    'x????import os????.yaml'
    >>> comment_text("a */ b")
    'a ?/ b'
    """
    text = _UNSAFE.sub("?", str(value))
    return text if len(text) <= limit else text[: limit - 3] + "..."
