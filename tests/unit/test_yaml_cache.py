"""Parsed YAML kept in platkit's cache (platkit/io/cache.py): the same mapping as a fresh parse,
read back without PyYAML, never kept for a text that failed, passed over when unreadable."""
import subprocess
import sys

import pytest

from platkit.errors import BadDescription
from platkit.io import cache
from platkit.io.description import load_yaml, parse_yaml

TEXT = """\
platform: stewart
base: &b {radius: 1.5, angles: [0, 120, 240]}
top: *b
flags: [yes, no, ~, 1e3, 0x10, "s"]
1: integer key
"""


@pytest.fixture
def cache_folder(tmp_path, monkeypatch):
    folder = tmp_path / "cache"
    monkeypatch.setenv("PLATKIT_CACHE_DIR", str(folder))
    return folder


def test_a_text_is_parsed_once_and_read_back_the_same(tmp_path, cache_folder):
    path = tmp_path / "d.yaml"
    path.write_text(TEXT)
    fresh = parse_yaml(TEXT, path)
    assert load_yaml(path) == fresh  # parsed and kept
    kept = list((cache_folder / "yaml").iterdir())
    assert len(kept) == 1
    again = load_yaml(path)  # read back
    assert again == fresh and again is not fresh
    assert [type(v) for v in again["flags"]] == [bool, bool, type(None), str, int, str]
    assert again[1] == "integer key"
    # an edited file is another text: parsed again
    path.write_text(TEXT.replace("1.5", "1.6"))
    assert load_yaml(path)["base"]["radius"] == 1.6
    assert len(list((cache_folder / "yaml").iterdir())) == 2


def test_a_cached_description_needs_no_pyyaml(tmp_path, cache_folder):
    path = tmp_path / "d.yaml"
    path.write_text(TEXT)
    load_yaml(path)
    code = (f"import sys; from platkit.io.description import load_yaml; d = load_yaml({str(path)!r}); "
            "print('yaml' in sys.modules, d['top']['radius'])")
    env = {"PLATKIT_CACHE_DIR": str(cache_folder), "PATH": "/usr/bin:/bin"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True).stdout
    assert out.split() == ["False", "1.5"]


def test_bad_texts_are_never_kept_and_fail_alike(tmp_path, cache_folder):
    path = tmp_path / "bad.yaml"
    for text, match in (("a: [1, 2\n", "line 2 is not valid YAML"), ("- 1\n- 2\n", "expected a YAML mapping"),
                        ("a: &x [1]\nb: &y [*x, *x, *x, *x, *x, *x, *x, *x, *x, *x]\n" + "".join(
                            f"c{i}: &z{i} [" + ", ".join([f"*{'y' if i == 0 else 'z' + str(i - 1)}"] * 10) + "]\n"
                            for i in range(5)), "expand to more than")):
        path.write_text(text)
        for _ in range(2):
            with pytest.raises(BadDescription, match=match):
                load_yaml(path)
    assert not (cache_folder / "yaml").exists() or not list((cache_folder / "yaml").iterdir())


def test_a_value_marshal_cannot_hold_is_parsed_each_time(tmp_path, cache_folder):
    path = tmp_path / "dated.yaml"
    path.write_text("recorded: 2026-11-25\n")
    assert str(load_yaml(path)["recorded"]) == "2026-11-25"
    assert str(load_yaml(path)["recorded"]) == "2026-11-25"
    assert not (cache_folder / "yaml").exists() or not list((cache_folder / "yaml").iterdir())


def test_an_unreadable_or_unwritable_cache_is_passed_over(tmp_path, cache_folder, monkeypatch):
    path = tmp_path / "d.yaml"
    path.write_text(TEXT)
    load_yaml(path)
    (kept,) = (cache_folder / "yaml").iterdir()
    kept.write_bytes(b"\x00garbage")
    assert load_yaml(path) == parse_yaml(TEXT, path)  # parsed again (and kept again)
    assert cache.cached_yaml(TEXT) == parse_yaml(TEXT, path)
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    monkeypatch.setenv("PLATKIT_CACHE_DIR", str(blocked))  # a file where the folder would be
    assert load_yaml(path) == parse_yaml(TEXT, path)
