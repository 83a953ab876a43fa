"""A termination asked for while a command publishes its outputs waits for the last of
them: an interruption never leaves some outputs without the others."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

CHILD = textwrap.dedent("""
    import os, signal, sys
    from pathlib import Path
    from graphcal.cli.common import install_signal_handlers, outputs_published_together

    install_signal_handlers()
    folder = Path(sys.argv[1])
    try:
        with outputs_published_together():
            os.kill(os.getpid(), signal.SIG{name})   # asked for before the first output
            (folder / "first.json").write_text("1")
            (folder / "second.html").write_text("2")
        (folder / "after.txt").write_text("not reached")
    except KeyboardInterrupt:
        sys.exit(130)
""")


@pytest.mark.parametrize(("name", "status"), [("TERM", 143), ("INT", 130)])
def test_a_signal_during_publishing_waits_for_every_output(tmp_path: Path, name: str,
                                                           status: int) -> None:
    done = subprocess.run([sys.executable, "-c", CHILD.replace("{name}", name),
                           str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == status, done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["first.json", "second.html"]
