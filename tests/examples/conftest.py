import contextlib
import runpy
from pathlib import Path

import pytest

from physar.rom._threads import single_blas_thread

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.fixture(scope="module")
def run_example(tmp_path_factory):
    """``run(name, one_blas_thread=False) -> (globals, output folder)``: examples/NAME run top to bottom in quick
    mode (``PHYSAR_EXAMPLE_QUICK=1``) into a fresh folder, once per test module."""
    done = {}

    def run(name: str, one_blas_thread: bool = False):
        if name not in done:
            out = tmp_path_factory.mktemp(Path(name).stem)
            with pytest.MonkeyPatch.context() as mp:
                mp.setenv("PHYSAR_EXAMPLE_QUICK", "1")
                mp.setenv("PHYSAR_EXAMPLE_OUT", str(out))
                with single_blas_thread() if one_blas_thread else contextlib.nullcontext():
                    done[name] = runpy.run_path(str(EXAMPLES / name)), out
        return done[name]

    return run

