"""Every message about a [[marker]] table names it one way, "[[marker]] id N" (its id; "[[marker]] table K"
when it has no integer id), after the file (issue 16: a review found "[[marker]] 2", "marker id 2",
"markers[1]"-like pydantic locations such as "[marker.1.size]", and "[marker]"). Each bad table of the
template is one line naming the file, the marker by its id and the key, and no other form of the name.

Mutants (tried): the pydantic location left as it was (``parse_project`` without ``_name_marker``: "[marker.1.size]",
"marker.1.id", "in [marker]"); the position instead of the id ("[[marker]] 2: id = 77 is outside", the former
message); the id-range check left to `load_project` only (`ar print-markers` then says "marker id 77 is outside"
without the file)."""
import re
import tomllib

import pytest
from typer.testing import CliRunner

from physar.ar.project import TEMPLATE, parse_project
from physar.cli.main import app
from physar.errors import ConfigError

SECOND = """
[[marker]]
id = 7
size = 0.04
center = [0.3, -0.001, 0.05]
normal = [0, -1, 0]
up = [0, 0, 1]
dictionary = "DICT_4X4_50"
"""
TWO = TEMPLATE.replace("\n[dots]", SECOND + "\n[dots]", 1)
OLD_FORMS = re.compile(r"\[marker\.\d|marker\.\d|in \[marker\]|\[\[marker\]\] \d|markers\[\d|marker id \d")


def _second(old, new):
    """The template with a second marker (id 7) whose line ``old`` is replaced by ``new``."""
    i = TWO.index(SECOND.strip())
    return TWO[:i] + TWO[i:].replace(old, new, 1)


CASES = [
    (_second("size = 0.04", "size = true"), "[[marker]] id 7: size: expected a number, got true"),
    (_second("size = 0.04", "size = -0.04"), "[[marker]] id 7: size: "),
    (_second("size = 0.04", "size = 0.04\ncolour = 1"), "unknown key 'colour' in [[marker]] id 7 (allowed: id,"),
    (_second("size = 0.04\n", ""), "missing key 'size' in [[marker]] id 7"),
    (_second("up = [0, 0, 1]", "up = [0, 1, 1]"), "[[marker]] id 7: up [0.0, 1.0, 1.0] must be perpendicular"),
    (_second("center = [0.3, -0.001, 0.05]", "center = [0.3, 0.05]"), "[[marker]] id 7: center: expected 3 values, got [0.3, 0.05]"),
    (_second("id = 7", "id = 77"), "[[marker]] id 77 is outside DICT_4X4_50 (ids 0-49)"),
    (_second("id = 7", "id = 0"), "[[marker]] id 0 is given twice"),
    (_second('dictionary = "DICT_4X4_50"', 'dictionary = "DICT_5X5_50"'),
     "[[marker]] id 7: dictionary 'DICT_5X5_50' differs from 'DICT_4X4_50' of [[marker]] id 0"),
    (_second("id = 7", "id = true"), "[[marker]] table 2: id: expected an integer, got true"),
    (_second("id = 7\n", ""), "missing key 'id' in [[marker]] table 2"),
]


@pytest.mark.parametrize("text, words", CASES, ids=[w[:40] for _, w in CASES])
def test_every_marker_table_error_names_the_table_by_its_id(text, words):
    with pytest.raises(ConfigError) as e:
        parse_project(tomllib.loads(text), "plate.toml")
    msg = str(e.value)
    assert msg.startswith("plate.toml: ") and words in msg and "\n" not in msg, msg
    assert not OLD_FORMS.search(msg) and "[top level]" not in msg, msg


def test_print_markers_names_the_file_and_the_marker(tmp_path):
    """`physar ar print-markers` reads only the project's tables: an id outside the dictionary is the same line
    as for `ar run` (before, printing's own "marker id 77 is outside DICT_4X4_50's range 0..49")."""
    p = tmp_path / "plate.toml"
    p.write_text(_second("id = 7", "id = 77"))
    r = CliRunner().invoke(app, ["ar", "print-markers", str(p), "-o", str(tmp_path / "m.pdf")])
    assert r.exit_code == 2 and not (tmp_path / "m.pdf").exists(), r.output
    err = [ln for ln in r.output.splitlines() if ln.startswith("error:")]
    assert err == [f"error: {p}: [[marker]] id 77 is outside DICT_4X4_50 (ids 0-49)"], r.output
