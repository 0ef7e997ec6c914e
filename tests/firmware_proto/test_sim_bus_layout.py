"""A simulated bus of any firmware backend refuses a layout it cannot serve with one typed
error that says what to change: no controller, two controllers at one address, or a list of
pixel counts that does not match the addresses."""

from __future__ import annotations

import pytest

from grassd.firmware_proto.errors import SimulatorError
from grassd.rigs.sim_backends import FIRMWARE_BACKENDS, open_bus


@pytest.mark.parametrize("firmware", FIRMWARE_BACKENDS)
@pytest.mark.parametrize(("addresses", "n_pixels", "words"), [
    ([], 4, "at least one controller"),
    ([1, 2, 1], 4, "share an address"),
    ([1, 2, 3], [4, 4], "2 pixel counts for 3 controllers"),
])
def test_bad_bus_layout_is_a_simulator_error(tmp_path, firmware, addresses, n_pixels, words):
    with pytest.raises(SimulatorError, match=words):
        open_bus(firmware, tmp_path, addresses, n_pixels=n_pixels)


def test_unknown_firmware_is_named():
    with pytest.raises(SimulatorError, match="unknown firmware 'fpga'.*model, posix, qemu"):
        open_bus("fpga", "/nonexistent", [1])
