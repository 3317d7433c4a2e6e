"""A SIGTERM (or Ctrl-C) that arrives while Python runs an object's ``__del__`` (a Warp array freed by the
collector) raises its KeyboardInterrupt there, and Python drops it ("Exception ignored in"): the command ran on and
wrote its output, exit 0 (seen once in test_signal_during_recon_synth_leaves_nothing). The signal is remembered, and
the next output that would take its place raises the interrupt instead: nothing is written.

Mutant (tried): no check before the commit (the file is written)."""
import os
import signal

import pytest

from physar.output import atomic_folder, atomic_path, sigterm_as_interrupt


class _Dies:
    def __init__(self, sig):
        self.sig = sig

    def __del__(self):
        os.kill(os.getpid(), self.sig)
        for _ in range(1000):   # the handler runs here, inside __del__, and its exception is dropped
            pass


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_interrupt_dropped_in_del_still_stops_the_write(tmp_path, sig):
    out, folder = tmp_path / "out.txt", tmp_path / "scene"
    with sigterm_as_interrupt():
        d = _Dies(sig)
        del d                                                   # the interrupt is raised and dropped
        with pytest.raises(KeyboardInterrupt), atomic_path(out) as tmp:
            tmp.write_text("complete")
        assert not out.exists()
        with atomic_path(out) as tmp:                           # acted on once: later writes go through
            tmp.write_text("complete")
        assert out.read_text() == "complete"
        d = _Dies(sig)
        del d
        with pytest.raises(KeyboardInterrupt), atomic_folder(folder) as tmp:
            (tmp / "a.txt").write_text("x")
    assert sorted(f.name for f in tmp_path.iterdir()) == ["out.txt"]
