"""The GPU context and the scan kernel, exercised through the Python module."""

import numpy as np
import pytest

from evsplat import _core
from evsplat.cli import main
from evsplat.gpu import adapter_info


def test_adapter_reports_name_and_limits():
    info = adapter_info()
    assert info["name"]
    assert info["max_storage_buffer_binding_size"] >= 128 * 2**20
    assert info["atomic_mode"] in ("Float", "Cas")


@pytest.mark.parametrize("n", [0, 1, 255, 256, 257, 1_000_003])
def test_gpu_exclusive_scan_matches_numpy_cumsum(n):
    rng = np.random.default_rng(n)
    values = rng.integers(0, 1000, size=n, dtype=np.uint32)
    expected = np.concatenate([[0], np.cumsum(values, dtype=np.uint64)[:-1]]).astype(np.uint32)
    np.testing.assert_array_equal(_core.exclusive_scan_u32(values)[:n], expected[:n])


def test_info_command_prints_adapter(capsys):
    assert main(["info"]) == 0
    out = capsys.readouterr().out
    assert "adapter" in out and "f32 atomics" in out
