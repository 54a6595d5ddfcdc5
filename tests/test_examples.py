"""The example files shipped inside the package (``servotune.examples``) and ``servotune init``.

- ``plants/`` and the package's copies cannot drift: every file of ``plants/`` is in the
  package, byte for byte, and the package holds nothing else but the LinuxCNC map and the
  autotune config;
- the library's example rig (the template of ``fit -o NEW.toml``, the trust chain's last
  fallback) is the package's copy, not a checkout's;
- ``write_examples`` / ``servotune init``: every file written, identical files left alone, a
  different file refused before anything is written (exit 3, one line) unless ``--force``;
  the README's commands then run in that directory;
- ``linuxcnc-map.toml`` is a map ``--map`` reads, the one the README shows.

An installed wheel, outside the repository: ``tests/test_wheel.py``.
"""

from __future__ import annotations

import doctest
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

import servotune
import servotune.examples
from servotune.cli import main
from servotune.examples import (
    EXAMPLES_DIR,
    ExamplesDifferError,
    example_names,
    example_path,
    write_examples,
)
from servotune.io.hal import read_hal_log
from servotune.io.hal_map import hal_settings
from servotune.rig import EXAMPLE_RIG_PATH, load_rig

ROOT = Path(__file__).resolve().parents[1]
PLANTS = ROOT / "plants"
MAP = "linuxcnc-map.toml"
NOT_IN_PLANTS = (MAP, "linuxcnc-autotune.toml")  # the LinuxCNC files: not rigs or specs


def test_plants_and_the_package_copies_are_the_same_bytes() -> None:
    in_plants = sorted(p.name for p in PLANTS.iterdir() if p.is_file())
    assert len(in_plants) >= 6
    assert sorted(example_names()) == sorted([*in_plants, *NOT_IN_PLANTS])
    for name in in_plants:
        assert example_path(name).read_bytes() == (PLANTS / name).read_bytes(), (
            f"plants/{name} and servotune/examples/{name} differ: copy the edited one over"
        )


def test_the_examples_are_in_the_package_not_the_checkout() -> None:
    package = Path(servotune.__file__).resolve().parent
    assert EXAMPLES_DIR == package / "examples"
    assert EXAMPLE_RIG_PATH == EXAMPLES_DIR / "pc-dual-servo.toml"
    assert PLANTS not in EXAMPLE_RIG_PATH.parents
    assert load_rig(EXAMPLE_RIG_PATH).name == "pc-dual-servo"
    with pytest.raises(ValueError, match=r"no example file 'nope\.toml'.*pc-dual-servo\.toml"):
        example_path("nope.toml")


def test_module_doctests() -> None:
    result = doctest.testmod(servotune.examples)
    assert result.attempted >= 4 and result.failed == 0


def test_write_examples_writes_skips_refuses_and_forces(tmp_path: Path) -> None:
    target = tmp_path / "a" / "plants"  # missing parents are made
    done = write_examples(target)
    assert [f.path.name for f in done] == list(example_names())
    assert {f.action for f in done} == {"wrote"}
    for f in done:
        assert f.path == target / f.path.name
        assert f.path.read_bytes() == example_path(f.path.name).read_bytes()
    assert not list(target.glob(".*"))  # no temporary file left

    again = write_examples(target)
    assert {f.action for f in again} == {"unchanged"}

    # one file edited, one removed: refused before anything is written
    edited = target / "gantry.toml"
    edited.write_text("# mine\n")
    (target / "pc-dual-servo.toml").unlink()
    with pytest.raises(ExamplesDifferError, match=r"gantry\.toml.*nothing written") as info:
        write_examples(target)
    assert info.value.paths == (edited,)
    assert isinstance(info.value, FileExistsError)
    assert edited.read_text() == "# mine\n"
    assert not (target / "pc-dual-servo.toml").exists()

    forced = {f.path.name: f.action for f in write_examples(target, force=True)}
    assert forced["gantry.toml"] == "replaced" and forced["pc-dual-servo.toml"] == "wrote"
    assert forced["gantry.spec.toml"] == "unchanged"
    assert edited.read_bytes() == example_path("gantry.toml").read_bytes()


def test_write_examples_refuses_what_is_in_the_way(tmp_path: Path) -> None:
    a_file = tmp_path / "f"
    a_file.write_text("x")
    with pytest.raises(NotADirectoryError):
        write_examples(a_file / "plants")
    (tmp_path / "d" / "gantry.toml").mkdir(parents=True)
    with pytest.raises(IsADirectoryError):
        write_examples(tmp_path / "d")
    assert sorted(p.name for p in (tmp_path / "d").iterdir()) == ["gantry.toml"]


def test_init_cli_writes_plants_then_the_readme_commands_run_there(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["init"]) == 0
    out, err = capsys.readouterr()
    assert out == ""  # stdout is for products
    lines = err.splitlines()
    assert lines[:-1] == [f"wrote {Path('plants') / n}" for n in example_names()]
    assert lines[-1].startswith("next: servotune rig plants/pc-dual-servo.toml")
    for n in example_names():
        assert (tmp_path / "plants" / n).read_bytes() == example_path(n).read_bytes()

    # a command of the README and of --help, as written, from that directory
    assert main(["rig", "plants/pc-dual-servo.toml", "--json"]) == 0
    assert '"rig": "pc-dual-servo"' in capsys.readouterr().out

    assert main(["init", "."]) == 0
    err = capsys.readouterr().err
    assert err.count("the same bytes: left alone") == len(example_names())


def test_init_cli_refuses_a_different_file_and_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plants = tmp_path / "lab" / "plants"
    plants.mkdir(parents=True)
    mine = plants / "pc-dual-servo.spec.toml"
    mine.write_text("# my limits\n")
    assert main(["init", str(tmp_path / "lab")]) == 3
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("servotune init: error: ")
    assert "pc-dual-servo.spec.toml" in err and "--force" in err
    assert sorted(p.name for p in plants.iterdir()) == ["pc-dual-servo.spec.toml"]
    assert mine.read_text() == "# my limits\n"

    assert main(["init", str(tmp_path / "lab"), "--force"]) == 0
    err = capsys.readouterr().err
    assert f"replaced {mine}" in err.splitlines()
    assert err.splitlines()[-1].startswith(f"next: cd {tmp_path / 'lab'}, then servotune rig")
    assert mine.read_bytes() == example_path(mine.name).read_bytes()

    a_file = tmp_path / "file"
    a_file.write_text("x")
    assert main(["init", str(a_file)]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is a file, not a directory" in err


def _readme_map() -> str:
    """The map file the README's LinuxCNC section shows (the ``toml`` block with ``[hal]``)."""
    blocks = re.findall(r"```toml\n(.*?)```", (ROOT / "README.md").read_text(), flags=re.S)
    return next(b for b in blocks if b.startswith("[hal]"))


def test_the_linuxcnc_map_is_read_by_map_and_is_the_readme_s(tmp_path: Path) -> None:
    path = example_path(MAP)
    settings = hal_settings(str(path))  # what `servotune fit CAPTURE --map FILE` reads
    assert settings is not None
    assert dict(settings.mapping) == {
        "cmd": "x-output",
        "pos": "x-pos-fb",
        "ref": "x-pos-cmd",
        "overruns": "sampler-overruns",
    }
    assert settings.columns == ("x-output", "x-pos-fb", "x-pos-cmd", "sampler-overruns")
    assert (settings.format, settings.period_s, settings.sample_number) == (
        "halsampler",
        0.001,
        True,
    )
    assert (settings.position_scale, settings.output_scale) == (2000, 1.0)
    # the README's block says the same (comments aside)
    assert tomllib.loads(_readme_map()) == tomllib.loads(path.read_text())

    # a capture recorded as its comment says (halsampler -t, four pins) reads with it
    n = 6
    cmd = np.array([0.0, 1.0, -1.0, 2.5, 0.0, 0.5])  # V (output scale 1)
    pos = np.arange(n) * 0.01  # mm: 20 counts per sample at 2000 counts/mm
    rows = "".join(f"{k} {cmd[k]:f} {pos[k]:f} {pos[k]:f} 0 \n" for k in range(n))
    capture = tmp_path / "capture.txt"
    capture.write_text(rows)
    log = read_hal_log(capture, settings)
    assert log.period_s == 0.001
    assert log.axis().cmd_v.tolist() == cmd.tolist()
    assert log.axis().pos_counts.tolist() == [20 * k for k in range(n)]
