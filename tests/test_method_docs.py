"""The docs' parameter tables agree with the library's method metadata
(pn_method_get_info / pn_method_get_param): docs/api.md has one table per
method under ``#### <method> parameters``, docs/scene-format.md the fiv bake
parameters (``#### fiv bake parameters``) and the ``[render]`` keys of every
method (``#### `[render]` keys by method``). The tables' format:

    | name | type | stage | default | range | unit | meaning |
    |---|---|---|---|---|---|---|
    | `overlap` | int | frame | 1 | [0, 2] |  | Several occluders: ... |

one row per parameter in the library's order (a method without parameters may
have no table); ``name`` in backticks, ``type``
int/float, ``stage`` frame/plan/bake, ``default`` and ``range`` ("[min, max]",
inclusive) as numbers (compared by value), ``unit`` the library's (empty when
it has none), ``meaning`` its doc sentence verbatim. ``penumbra methods
--markdown`` prints exactly these tables."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from penumbra.cli import main
from penumbra.methods import PARAM_TABLE_HEADER, catalog, markdown_table, spec

DOCS = Path(__file__).resolve().parents[1] / "docs"


def _cells(line: str) -> list[str]:
    return [c.strip() for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]]


def tables_under(text: str, heading: str) -> dict[str, list[str] | None]:
    """For each line matching the regex ``heading`` (one group: the key), the
    lines of the first table after it before the next heading (None: no table)."""
    out: dict[str, list[str] | None] = {}
    lines = text.splitlines()
    for i, line in enumerate(lines):
        m = re.fullmatch(heading, line.strip())
        if not m:
            continue
        assert m.group(1) not in out, f"two '{line}' headings"
        table = None
        for j in range(i + 1, len(lines)):
            if lines[j].startswith("#"):
                break
            if lines[j].startswith("|"):
                k = j
                while k < len(lines) and lines[k].startswith("|"):
                    k += 1
                table = lines[j:k]
                break
        out[m.group(1)] = table
    return out


def _number(text: str, where: str) -> float:
    try:
        return float(text)
    except ValueError:
        pytest.fail(f"{where}: {text!r} is not a number")


def _same(a: float, b: float) -> bool:
    return a == b or (math.isfinite(a) and math.isfinite(b) and abs(a - b) <= 1e-6 * max(abs(a), abs(b)))


def check_param_table(table: list[str] | None, params, where: str) -> None:
    if table is None and not params:  # a method without parameters may say so in words
        return
    assert table is not None, f"{where}: no table"
    assert " ".join(table[0].split()) == PARAM_TABLE_HEADER, f"{where}: header {table[0]!r}"
    rows = [_cells(r) for r in table[2:]]
    names = [r[0].strip("`") for r in rows]
    assert names == [p.name for p in params], f"{where}: parameters {names}, the library has {[p.name for p in params]}"
    for r, p in zip(rows, params):
        at = f"{where}, {p.name}"
        assert len(r) == 7, f"{at}: {len(r)} cells"
        assert r[0] == f"`{p.name}`", f"{at}: name cell {r[0]!r}"
        assert (r[1], r[2]) == (p.type, p.stage), f"{at}: type/stage {r[1]}/{r[2]}, the library's {p.type}/{p.stage}"
        assert _same(_number(r[3], at), p.default), f"{at}: default {r[3]}, the library's {p.default}"
        m = re.fullmatch(r"\[\s*(\S+)\s*,\s*(\S+)\s*\]", r[4])
        assert m, f"{at}: range {r[4]!r} is not [min, max]"
        lo, hi = _number(m.group(1), at), _number(m.group(2), at)
        assert _same(lo, p.min) and _same(hi, p.max), f"{at}: range {r[4]}, the library's {p.range_text()}"
        assert r[5] == p.unit, f"{at}: unit {r[5]!r}, the library's {p.unit!r}"
        assert r[6] == p.doc, f"{at}: meaning {r[6]!r}, the library's {p.doc!r}"


def test_the_checker_accepts_what_penumbra_methods_markdown_prints(capsys):
    assert main(["methods", "--markdown"]) == 0
    out = capsys.readouterr().out
    tables = tables_under(out, r"#### (\S+) parameters")
    assert list(tables) == list(catalog())
    for name, table in tables.items():
        check_param_table(table, spec(name).params, f"methods --markdown, {name}")
    with pytest.raises(AssertionError, match="default"):  # and it notices a wrong default
        check_param_table(markdown_table(spec("fiv").params).replace("| 17 |", "| 18 |").splitlines(),
                          spec("fiv").params, "edited")


def test_api_md_parameter_tables_match_the_library():
    text = (DOCS / "api.md").read_text(encoding="utf-8")
    tables = tables_under(text, r"#### (\S+) parameters")
    assert sorted(tables) == sorted(catalog()), f"docs/api.md has '#### <method> parameters' for {sorted(tables)}"
    for name, table in tables.items():
        check_param_table(table, spec(name).params, f"docs/api.md '#### {name} parameters'")


def test_scene_format_fiv_table_matches_the_librarys_bake_parameters():
    text = (DOCS / "scene-format.md").read_text(encoding="utf-8")
    tables = tables_under(text, r"#### (fiv) bake parameters")
    check_param_table(tables.get("fiv"), spec("fiv").params_of("bake"), "docs/scene-format.md '#### fiv bake parameters'")


def test_scene_format_lists_each_methods_render_keys():
    text = (DOCS / "scene-format.md").read_text(encoding="utf-8")
    table = tables_under(text, r"#### `\[(render)\]` keys by method").get("render")
    assert table is not None and _cells(table[0]) == ["method", "keys"]
    rows = {r[0].strip("`"): r[1] for r in map(_cells, table[2:])}
    assert list(rows) == list(catalog())
    for name, keys in rows.items():
        want = [p.name for p in spec(name).params if p.stage != "bake"]
        got = [] if keys == "none" else [k.strip().strip("`") for k in keys.split(",")]
        assert got == want, f"docs/scene-format.md [render] keys of {name}: {got}, the library's {want}"
