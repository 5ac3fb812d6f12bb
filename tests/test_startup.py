"""Start-up: a flight imports only what it uses.

``scipy.signal`` takes about a second to import and nothing in a run needs it (the washout's
filters are designed with ``scipy.linalg``, which numba imports anyway; the perception models
that use ``scipy.signal`` serve ``report``, ``omct`` and the tuner, and import it there).
"""

from __future__ import annotations

import subprocess
import sys


def test_a_flight_does_not_import_scipy_signal(tmp_path):
    code = (
        "import sys\n"
        "from motionbase.cli import main\n"
        f"code = main(['fly', 'c1723', '--duration', '1', '--out', {str(tmp_path / 'f.mcap')!r}])\n"
        "print(code, 'scipy.signal' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split()[-2:] == ["0", "False"], out.stdout + out.stderr
