import pytest

from physar.rom._threads import single_blas_thread


@pytest.fixture(scope="module", autouse=True)
def _one_blas_thread():
    """Reference FE solves and ROM builds with one BLAS thread: two spinning OpenBLAS pools on a small
    shared machine slowed the module fixtures 5-15x (see physar.rom._threads)."""
    with single_blas_thread():
        yield
