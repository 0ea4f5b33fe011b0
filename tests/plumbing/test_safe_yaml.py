"""The one YAML loader: alias bombs, absurd nesting and repeated keys are refused with one line
naming the file and the line (issue 9, defects 1, 10, 11, 12), and nothing expands a bomb."""

from __future__ import annotations

import resource
import time
from pathlib import Path

import pytest

from convodrive.cli.main import main
from convodrive.plumbing.errors import InputFileError
from convodrive.plumbing.safe_yaml import MAX_ALIASES, MAX_DEPTH, load_yaml_file, parse_scalar, parse_yaml
from convodrive.retargeting import load_profile
from convodrive.retargeting.profile import resolve_profile_path


def laughs(levels: int, key: str = "description") -> str:
    """A "billion laughs" document: each level lists nine aliases of the one before (9**levels)."""
    lines = ['l0: &l0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for i in range(1, levels + 1):
        lines.append(f"l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 9)}]")
    return "\n".join(lines) + f"\n{key}: *l{levels}\n"


def refused(text: str, *needles: str) -> str:
    with pytest.raises(InputFileError) as info:
        parse_yaml(text, "doc.yaml")
    message = str(info.value)
    assert "\n" not in message and len(message) < 200, message
    for needle in needles:
        assert needle in message, (needle, message)
    return message


def test_billion_laughs_is_refused_before_anything_expands_it() -> None:
    start = time.perf_counter()
    refused(laughs(9), "doc.yaml: line 6: aliases expand to more than 100,000 values")
    assert time.perf_counter() - start < 5


def test_many_aliases_are_refused_and_a_few_are_fine() -> None:
    few = "base: &b {gain: 1}\n" + "".join(f"j{i}: *b\n" for i in range(10))
    assert parse_yaml(few, "x")["j9"] == {"gain": 1}
    many = "base: &b 1\n" + "".join(f"j{i}: *b\n" for i in range(MAX_ALIASES + 1))
    refused(many, f"more than {MAX_ALIASES} aliases")


def test_merge_keys_may_override_what_they_merge() -> None:
    doc = parse_yaml("d: &d {gain: 1, offset: 0}\nj: {<<: *d, gain: 2}\n", "x")
    assert doc["j"] == {"gain": 2, "offset": 0}


@pytest.mark.parametrize("text", ["[" * 5000 + "]" * 5000, "{a: " * 5000 + "1" + "}" * 5000])
def test_absurd_nesting_is_one_line(text: str) -> None:
    """Defect 10: YAML nested 5,000 deep gave a RecursionError traceback."""
    refused(text, f"nested deeper than {MAX_DEPTH} levels")


def test_block_nesting_too() -> None:
    refused("".join(" " * i + f"k{i}:\n" for i in range(200)) + " " * 200 + "v\n", "nested deeper")


def test_duplicate_keys_name_both_lines() -> None:
    refused("a: 1\nb: 2\na: 3\n", "line 3: duplicate key 'a' (first at line 1)")
    assert parse_yaml("a: 1\n'1': 2\n1: 3\n", "x") == {"a": 1, "1": 2, 1: 3}  # distinct keys


def test_self_reference_is_refused() -> None:
    refused("a: &x [1, *x]\n", "refers to the collection that contains it")


def test_syntax_error_keeps_the_reason() -> None:
    """Defect 12: the message said "not valid YAML at line N" and dropped why."""
    refused("joints: [unclosed\n", "doc.yaml: not valid YAML at line 2: expected ',' or ']', but got '<stream end>'")
    refused("a: b: c\n", "not valid YAML at line 1: mapping values are not allowed here")


def test_files(tmp_path: Path) -> None:
    (tmp_path / "ok.yaml").write_text("a: 1\n")
    assert load_yaml_file(tmp_path / "ok.yaml") == {"a": 1}
    with pytest.raises(InputFileError, match="no such file"):
        load_yaml_file(tmp_path / "absent.yaml")
    with pytest.raises(InputFileError, match="is a folder"):
        load_yaml_file(tmp_path)
    (tmp_path / "big.yaml").write_bytes(b"# " + b"x" * (5 * 1024 * 1024))
    with pytest.raises(InputFileError, match="larger than 4 MiB"):
        load_yaml_file(tmp_path / "big.yaml")


def test_command_line_values() -> None:
    assert parse_scalar("3") == 3 and parse_scalar("true") is True and parse_scalar("face") == "face"
    assert parse_scalar("[unclosed") == "[unclosed" and parse_scalar("") == ""
    assert parse_scalar("*x") == "*x"  # an undefined alias is just text


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def test_bomb_in_a_profile_description(tmp_path: Path) -> None:
    """Defect 1: a bomb under description: or limits: exhausted memory."""
    head = resolve_profile_path("servo_head").read_text()
    for key in ("description", "joints"):
        path = tmp_path / f"{key}.yaml"
        path.write_text(head.replace("name: servo_head\n", laughs(9, key if key == "description" else "bomb")))
        before = _peak_rss_mb()
        with pytest.raises(InputFileError, match="aliases expand to more than"):
            load_profile(path)
        assert _peak_rss_mb() - before < 200


def test_bomb_in_run_config_generator_options_is_one_short_line(capsys, tmp_path: Path, tone_dialogue: Path) -> None:  # type: ignore[no-untyped-def]
    """Defect 1: a bomb in generator options wrote gigabytes to stderr."""
    path = tmp_path / "run.yaml"
    path.write_text(laughs(9, "bomb") + "generator: {procedural: {expressiveness: *l9}}\n")
    assert main(["drive", str(tone_dialogue), "--config", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert len(err) < 300 and err.count("\n") == 1 and "aliases expand" in err, err
    # below the limit, a shared list reaching an option is still echoed in one short line
    path.write_text(laughs(3, "bomb") + "generator: {procedural: {expressiveness: *l3}}\n")
    assert main(["drive", str(tone_dialogue), "--config", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert len(err) < 300 and err.count("\n") == 1 and "option 'expressiveness' must be a number" in err, err


def test_a_5000_digit_integer_in_a_profile_is_one_line(capsys, tmp_path: Path, tone_dialogue: Path) -> None:  # type: ignore[no-untyped-def]
    """Issue 31 defect 15: PyYAML's int() past Python's int-string limit was a 46-line traceback."""
    path = tmp_path / "p.yaml"
    head = resolve_profile_path("servo_head").read_text()
    assert "max_velocity: 3.0" in head
    path.write_text(head.replace("max_velocity: 3.0", "max_velocity: " + "9" * 5000, 1))
    assert main(["drive", str(tone_dialogue), "--config", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(path) in err and "max_velocity: an integer of 5000 digits is too long" in err, (
        err
    )
