"""bench/oclgrind_check.py's probe of Oclgrind's own faults, checked without Oclgrind: Oclgrind
26.03.1's uninitialised-value plugin called the bytes of a filled buffer uninitialised (past
its last host store's length) and crashed on a host store from a second thread; the script
refuses such a build (exit status 2, one line naming bench/oclgrind-26.03.patch) before any
family runs, and its probe passes on a correct device."""

import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench"
sys.path.insert(0, str(BENCH))

import oclgrind_check  # noqa: E402


def test_probe_passes_on_a_correct_device(runtime):
    oclgrind_check.child_probe()  # raises SystemExit when a byte reads wrong


@pytest.mark.parametrize("fault", ["errors", "crash"])
def test_an_oclgrind_failing_the_probe_is_refused(tmp_path, monkeypatch, capsys, fault):
    ran = []

    def run_family(family, env, log_dir, timeout):
        ran.append(family)
        errors, status = (7, 0) if fault == "errors" else (0, -11)
        return {"errors": errors, "exit_status": status, "log": str(log_dir / f"{family}.log")}

    monkeypatch.setattr(oclgrind_check, "oclgrind_environment", lambda lib, icd: {})
    monkeypatch.setattr(oclgrind_check, "run_family", run_family)
    with pytest.raises(SystemExit) as exit_info:
        oclgrind_check.main(["--out", str(tmp_path)])
    assert exit_info.value.code == 2
    assert ran == ["probe"]  # no family ran
    message = capsys.readouterr().err.strip()
    assert "\n" not in message
    assert oclgrind_check.PATCH in message
    assert (BENCH.parent / oclgrind_check.PATCH).is_file()
