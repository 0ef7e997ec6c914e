"""Which GPU backends Taichi can find here: the Vulkan devices this machine offers, read from the
Vulkan loader (``libvulkan.so.1``), and whether NVIDIA's CUDA driver is installed.

Taichi's ``gpu`` arch takes CUDA where it finds it, else Vulkan; and on a machine without a
GPU, Mesa's lavapipe (Debian's ``mesa-vulkan-drivers``) is a Vulkan device too: one that runs
on the CPU, through LLVM. Taichi names neither the device nor its kind, so
:func:`grassd.sim.backend.init` asks the loader here, to tell the user when ``--arch gpu`` runs
on the CPU after all (measured on 2 cores: about 30x slower than Taichi's own CPU backend).

Taichi 1.7.4's ``gpu`` arch does not fall back to the CPU where it finds no GPU: with no CUDA
device, it goes on to Vulkan and the process dies there (a segmentation fault), whether the
Vulkan loader is missing, lists no driver, or has a driver without a device.
:func:`init <grassd.sim.backend.init>` therefore hands Taichi the ``gpu`` arch only where
:func:`cuda_device_count` or :func:`vulkan_devices` names a device, and takes the CPU itself
elsewhere.

Both are asked through :mod:`ctypes`: the CUDA driver API's ``cuInit`` and
``cuDeviceGetCount``; the Vulkan loader's ``vkCreateInstance``, ``vkEnumeratePhysicalDevices``,
``vkGetPhysicalDeviceProperties`` and ``vkDestroyInstance`` (Vulkan 1.0). No Python binding is
needed for six calls.
"""

from __future__ import annotations

import ctypes
import ctypes.util
from dataclasses import dataclass

#: VkPhysicalDeviceType (Vulkan 1.0, section "Devices"), by value
DEVICE_KINDS = {0: "other", 1: "integrated GPU", 2: "discrete GPU", 3: "virtual GPU", 4: "cpu"}
_STRUCTURE_TYPE_INSTANCE_CREATE_INFO = 1
_SUCCESS, _INCOMPLETE = 0, 5
# VkPhysicalDeviceProperties: apiVersion, driverVersion, vendorID, deviceID (uint32 each), then
# deviceType (a 32-bit enum) at byte 16 and deviceName (char[256]) at byte 20; the limits after
# them make the struct 824 bytes on 64-bit Linux. A larger buffer leaves room to spare.
_PROPERTIES_BYTES = 4096
_TYPE_OFFSET, _NAME_OFFSET, _NAME_BYTES = 16, 20, 256


@dataclass(frozen=True)
class VulkanDevice:
    """One physical device as the loader lists it: its name (e.g. ``"llvmpipe (LLVM 15.0.6,
    256 bits)"``) and kind (a value of :data:`DEVICE_KINDS`; ``"cpu"``: a software
    implementation running on this machine's processors)."""

    name: str
    kind: str

    @property
    def on_cpu(self) -> bool:
        """Whether the device runs on the host's processors (a software Vulkan)."""
        return self.kind == "cpu"


class _InstanceCreateInfo(ctypes.Structure):
    _fields_ = [("sType", ctypes.c_uint32), ("pNext", ctypes.c_void_p),
                ("flags", ctypes.c_uint32), ("pApplicationInfo", ctypes.c_void_p),
                ("enabledLayerCount", ctypes.c_uint32),
                ("ppEnabledLayerNames", ctypes.c_void_p),
                ("enabledExtensionCount", ctypes.c_uint32),
                ("ppEnabledExtensionNames", ctypes.c_void_p)]


def cuda_device_count() -> int:
    """How many CUDA devices NVIDIA's driver (``libcuda.so.1``, what Taichi's CUDA backend
    loads) offers here: 0 where the driver is not installed, fails to initialise (e.g. in a
    container without the device nodes) or has no device."""
    for name in ("libcuda.so.1", "libcuda.so"):
        try:
            cuda = ctypes.CDLL(name)
        except OSError:
            continue
        count = ctypes.c_int(0)
        try:
            if cuda.cuInit(0) != _SUCCESS:
                return 0
            if cuda.cuDeviceGetCount(ctypes.byref(count)) != _SUCCESS:
                return 0
        except AttributeError:  # a library of that name that is no CUDA driver
            return 0
        return max(count.value, 0)
    return 0


def vulkan_loader_present() -> bool:
    """Whether the Vulkan loader (Debian: ``libvulkan1``) is installed, devices or not."""
    return _loader() is not None


def _loader() -> ctypes.CDLL | None:
    """The Vulkan loader, or None where it is not installed (Debian: ``libvulkan1``)."""
    for name in ("libvulkan.so.1", ctypes.util.find_library("vulkan")):
        if name:
            try:
                return ctypes.CDLL(name)
            except OSError:
                continue
    return None


def vulkan_devices() -> list[VulkanDevice]:
    """The physical devices the Vulkan loader lists, in its order; empty where there is no
    loader, no driver (an ICD), or the instance cannot be created."""
    vk = _loader()
    if vk is None:
        return []
    info = _InstanceCreateInfo(sType=_STRUCTURE_TYPE_INSTANCE_CREATE_INFO)
    instance = ctypes.c_void_p()
    if vk.vkCreateInstance(ctypes.byref(info), None, ctypes.byref(instance)) != _SUCCESS:
        return []
    try:
        count = ctypes.c_uint32(0)
        if vk.vkEnumeratePhysicalDevices(instance, ctypes.byref(count), None) != _SUCCESS:
            return []
        handles = (ctypes.c_void_p * count.value)()
        if vk.vkEnumeratePhysicalDevices(instance, ctypes.byref(count), handles) not in (
                _SUCCESS, _INCOMPLETE):
            return []
        devices = []
        for handle in handles[:count.value]:
            props = ctypes.create_string_buffer(_PROPERTIES_BYTES)
            vk.vkGetPhysicalDeviceProperties(ctypes.c_void_p(handle), props)
            kind = int.from_bytes(props.raw[_TYPE_OFFSET:_TYPE_OFFSET + 4], "little")
            name = props.raw[_NAME_OFFSET:_NAME_OFFSET + _NAME_BYTES].split(b"\0", 1)[0]
            devices.append(VulkanDevice(name.decode("utf-8", "replace"),
                                        DEVICE_KINDS.get(kind, "other")))
        return devices
    finally:
        vk.vkDestroyInstance(instance, None)
