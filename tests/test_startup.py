"""Start-up: a flight imports only what it uses and, once numba's cache is filled, compiles
nothing.

``scipy.signal`` takes about a second to import and nothing in a run needs it (the washout's
filters are designed with ``scipy.linalg``, which numba imports anyway; the perception models
that use ``scipy.signal`` serve ``report``, ``omct`` and the tuner, and import it there).
"""

from __future__ import annotations

import subprocess
import sys

import pytest


def test_a_flight_does_not_import_scipy_signal(tmp_path):
    code = (
        "import sys\n"
        "from motionbase.cli import main\n"
        f"code = main(['fly', 'c1723', '--duration', '1', '--out', {str(tmp_path / 'f.mcap')!r}])\n"
        "print(code, 'scipy.signal' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split()[-2:] == ["0", "False"], out.stdout + out.stderr


#: Runs a command in this process and prints how many functions numba compiled for it.
_COUNT_COMPILES = """
import sys

import pytest
from numba.core import event
compiled = []
class Count(event.Listener):
    def on_start(self, e):
        compiled.append(e.data["dispatcher"].py_func.__qualname__)
    def on_end(self, e):
        pass
event.register("numba:compile", Count())
from motionbase.cli import main
code = main(sys.argv[1:])
print(code, compiled)
"""


@pytest.mark.parametrize("robot", [[], ["--planar"], ["--platform", "stewart6"]])
def test_a_second_process_compiles_nothing(tmp_path, robot):
    # Every compiled function of a flight comes from numba's on-disk cache once a first
    # process has filled it: a function compiled in every process (typed-list methods built
    # from Python, a kernel without cache=True) costs up to a second of each start-up.
    args = ["fly", "c1723", "--duration", "0.5", "--out", str(tmp_path / "f.mcap"), *robot]
    for _ in range(2):
        out = subprocess.run(
            [sys.executable, "-c", _COUNT_COMPILES, *args], capture_output=True, text=True
        )
    assert out.stdout.splitlines()[-1:] == ["0 []"], out.stdout + out.stderr


def test_a_plug_in_kernel_of_another_signature_is_refused_by_name():
    from motionbase import stages
    from motionbase.washout.classical import ClassicalWashout

    with pytest.raises(TypeError, match="is not a numba function that compiles as"):
        stages.kernel_list(ClassicalWashout.step_kernel, stages.SOLVE_LIST)
    with pytest.raises(TypeError, match="is not a numba function that compiles as"):
        stages.kernel_list(len, stages.STEP_LIST)
    held = stages.kernel_list(ClassicalWashout.step_kernel, stages.STEP_LIST)
    assert len(held) == 1


def test_a_lazily_compiled_plug_in_kernel_is_compiled_for_its_list():
    import numba
    import numpy as np

    from motionbase import stages

    @numba.njit
    def track(params, state, achieved):  # a plug-in's kernel without a signature
        state[:] = params[0] * achieved

    held = stages.kernel_list(track, stages.TRACK_LIST)
    state = np.zeros(3)
    held[0](np.array([2.0]), state, np.array([1.0, 2.0, 3.0]))
    np.testing.assert_array_equal(state, [2.0, 4.0, 6.0])
