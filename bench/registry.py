"""All table and figure specs by id, importable without torch.

Ids: every ``bench/tabNN.py`` module, each defining ``SPEC`` (found, not listed: a new table is a new
module) and the figure ids of ``bench.figures``. :func:`normalize_id` accepts ``tab03``, ``tab3``, ``3``,
``03``, ``III``, ``repro-tab3`` (tox env names) and ``fig_mdc``; an unknown id raises ``KeyError``
listing the valid ones.
"""

from __future__ import annotations

import importlib
import pkgutil
import re
from functools import cache
from pathlib import Path

from bench.spec import Spec


def _table_modules() -> tuple[str, ...]:
    """Names of the ``bench/tabNN.py`` modules, in number order."""
    names = [m.name for m in pkgutil.iter_modules([str(Path(__file__).parent)])]
    return tuple(sorted(n for n in names if re.fullmatch(r"tab\d\d", n)))


TABLE_IDS: tuple[str, ...] = _table_modules()
_ROMAN = "I II III IV V VI VII VIII IX X XI XII XIII XIV XV XVI XVII XVIII XIX".split()


@cache
def _figures() -> dict[str, Spec]:
    from bench.figures import FIGURES

    return {f.id: f for f in FIGURES}


def figure_ids() -> list[str]:
    return list(_figures())


def list_specs(what: str = "all") -> list[str]:
    """Spec ids in paper order: ``"tables"``, ``"figures"`` or ``"all"``."""
    if what not in ("all", "tables", "figures"):
        raise ValueError(f"list_specs: what must be 'all', 'tables' or 'figures', got {what!r}")
    out: list[str] = []
    if what in ("all", "tables"):
        out += TABLE_IDS
    if what in ("all", "figures"):
        out += figure_ids()
    return out


def normalize_id(text: str) -> str:
    """Canonical spec id for any accepted spelling; ``KeyError`` lists the valid ids."""
    raw = text.strip()
    key = raw.lower()
    key = re.sub(r"^repro-", "", key)
    if key in _figures():
        return key
    m = re.fullmatch(r"(?:tab(?:le)?[-_ ]?)?0*(\d{1,2})", key)
    if m and f"tab{int(m.group(1)):02d}" in TABLE_IDS:
        return f"tab{int(m.group(1)):02d}"
    roman = re.sub(r"^(?:tab(?:le)?[-_ ]?)", "", raw.strip(), flags=re.I).upper()
    if roman in _ROMAN:
        return f"tab{_ROMAN.index(roman) + 1:02d}"
    raise KeyError(
        f"unknown table/figure id {text!r}; valid ids: {', '.join(list_specs())} "
        f"(also accepted: 3, tab3, repro-tab3, III)"
    )


def get_spec(spec_id: str) -> Spec:
    """The spec for any accepted id spelling."""
    sid = normalize_id(spec_id)
    if sid in _figures():
        return _figures()[sid]
    return importlib.import_module(f"bench.{sid}").SPEC


def parse_selection(items: list[str] | None) -> list[str]:
    """``--tables 3,17 fig_mdc`` -> canonical ids (comma or space separated; ``all``/None = everything)."""
    if not items:
        return list_specs()
    ids: list[str] = []
    for item in items:
        for part in filter(None, re.split(r"[,\s]+", item)):
            if part.lower() in ("all", "repro-all"):
                ids += list_specs()
            elif part.lower() in ("tables", "figures"):
                ids += list_specs(part.lower())
            else:
                ids.append(normalize_id(part))
    return list(dict.fromkeys(ids))
