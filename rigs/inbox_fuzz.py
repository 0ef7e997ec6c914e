"""Hostile light bundles, made as an attacker with write access to the inbox would.

Two sources, shared by the tests (``tests/daemon/runtime/test_hostile_bundles.py``,
``tests/daemon/store/test_inbox_fuzz.py``) and the benchmark (``bench_hostile``):

* :data:`ATTACKS`: each proven attack and its neighbours, a function that fills a bundle
  directory, with a word its rejection reason holds;
* :func:`random_bundle`: a random bundle from a seeded generator: file kinds (regular, FIFO,
  symbolic link, directory, socket, hard link, sparse giant), sizes, names (newlines, escape
  sequences, long, non-ASCII) and manifests (valid, mutated, truncated, nested, random bytes).
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import stat
import struct
import tempfile
import threading
import zlib
from collections.abc import Callable
from pathlib import Path

import numpy as np

from grassd.daemon.core.safe_text import storable
from grassd.daemon.core.store.history import History
from grassd.daemon.core.store.ingest import FLAT_SUFFIXES, Inbox
from grassd.sim.hdri import default_site_hdri

#: a poll that takes longer is taken for blocked (a FIFO open, an endless read)
POLL_LIMIT_S = 20.0
SITE = default_site_hdri()
#: a valid manifest (light of 21 June 2026, 08:00 at +09:00)
MANIFEST = 'timestamp = 2026-06-21T08:00:00+09:00\nhdri = "sky.exr"\nambient_lux = 1000.0\n'


def _sky(tmp: Path) -> None:
    shutil.copy(SITE, tmp / "sky.exr")


def fifo_manifest(tmp: Path, manifest: str = MANIFEST) -> None:
    """manifest.toml is a FIFO (an open() without O_NONBLOCK blocks for ever)."""
    _sky(tmp)
    os.mkfifo(tmp / "manifest.toml")


def dev_zero_manifest(tmp: Path, manifest: str = MANIFEST) -> None:
    """manifest.toml is a link to /dev/zero (a read without a cap never ends)."""
    _sky(tmp)
    os.symlink("/dev/zero", tmp / "manifest.toml")


def nested_toml_100k(tmp: Path, manifest: str = MANIFEST) -> None:
    """100 kB of nested TOML arrays (over the manifest cap)."""
    _sky(tmp)
    (tmp / "manifest.toml").write_text("x = " + "[" * 50_000 + "]" * 50_000 + "\n")


def nested_toml(tmp: Path, manifest: str = MANIFEST) -> None:
    """40 kB of nested TOML arrays: under the cap, past the parser's recursion limit."""
    _sky(tmp)
    (tmp / "manifest.toml").write_text("x = " + "[" * 20_000 + "]" * 20_000 + "\n")


def nested_json(tmp: Path, manifest: str = MANIFEST) -> None:
    """40 kB of nested JSON arrays: under the cap, past the parser's recursion limit."""
    _sky(tmp)
    (tmp / "manifest.json").write_text('{"x": ' + "[" * 20_000 + "]" * 20_000 + "}")


def reason_txt_directory(tmp: Path, manifest: str = MANIFEST) -> None:
    """A bad bundle holding a directory named reason.txt (where the reason is written)."""
    _sky(tmp)
    (tmp / "reason.txt").mkdir()
    (tmp / "reason.txt" / "inside").write_text("x")
    (tmp / "manifest.toml").write_text("this is not TOML [[[\n")


def huge_manifest_missing_file(tmp: Path, manifest: str = MANIFEST) -> None:
    """A 3 MB manifest naming a file that never arrives (parsed again on every scan)."""
    (tmp / "manifest.toml").write_text(manifest + "# " + "x" * 3_000_000 + "\n")


def hdri_link_to_huge_file(tmp: Path, manifest: str = MANIFEST) -> None:
    """The HDRI is a link to a 4 GiB (sparse) readable file: hashing it takes minutes."""
    huge = tmp.parent.parent / "huge.bin"
    with open(huge, "wb") as fh:
        fh.truncate(4 << 30)
    os.symlink(huge, tmp / "sky.exr")
    (tmp / "manifest.toml").write_text(manifest)


def hdri_dev_zero(tmp: Path, manifest: str = MANIFEST) -> None:
    """The HDRI is a link to /dev/zero."""
    os.symlink("/dev/zero", tmp / "sky.exr")
    (tmp / "manifest.toml").write_text(manifest)


def hdri_fifo(tmp: Path, manifest: str = MANIFEST) -> None:
    """The HDRI is a FIFO."""
    os.mkfifo(tmp / "sky.exr")
    (tmp / "manifest.toml").write_text(manifest)


def hdri_device(tmp: Path, manifest: str = MANIFEST) -> None:
    """The HDRI is a character device with /dev/zero's numbers (needs root: else a FIFO)."""
    if os.geteuid() == 0:
        os.mknod(tmp / "sky.exr", 0o600 | stat.S_IFCHR, os.makedev(1, 5))
    else:
        os.mkfifo(tmp / "sky.exr")
    (tmp / "manifest.toml").write_text(manifest)


def hdri_socket(tmp: Path, manifest: str = MANIFEST) -> None:
    """The HDRI is a Unix socket."""
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        s.bind(str(tmp / "sky.exr"))
    finally:
        s.close()
    (tmp / "manifest.toml").write_text(manifest)


def hdri_hard_link(tmp: Path, manifest: str = MANIFEST) -> None:
    """The HDRI is a hard link to someone else's file."""
    other = tmp.parent.parent / f"someone-elses-{tmp.name}.exr"
    shutil.copy(SITE, other)
    os.link(other, tmp / "sky.exr")
    (tmp / "manifest.toml").write_text(manifest)


def hdri_directory(tmp: Path, manifest: str = MANIFEST) -> None:
    """A directory where the HDRI file belongs."""
    (tmp / "sky.exr").mkdir()
    (tmp / "manifest.toml").write_text(manifest)


def stray_fifo(tmp: Path, manifest: str = MANIFEST) -> None:
    """A valid bundle plus a FIFO the manifest does not name."""
    _sky(tmp)
    os.mkfifo(tmp / "notes.txt")
    (tmp / "manifest.toml").write_text(manifest)


def too_many_entries(tmp: Path, manifest: str = MANIFEST) -> None:
    """A valid bundle plus 200 small files."""
    _sky(tmp)
    for k in range(200):
        (tmp / f"extra{k}.txt").write_text("x")
    (tmp / "manifest.toml").write_text(manifest)


def not_utf8(tmp: Path, manifest: str = MANIFEST) -> None:
    """A manifest that is not UTF-8."""
    _sky(tmp)
    (tmp / "manifest.toml").write_bytes(b'timestamp = 2026-06-21T08:00:00+09:00\n'
                                        b'hdri = "\xff\xfe"\n')


# --------------------------------------------------------------------------- hostile EXRs
# The Python binding needs every pixel in memory to write a part, so the hostile files are
# written here by hand (OpenEXR file layout 2.0: headers, offset tables, ZIP chunks of zeros).


def _attr(name: str, typ: str, value: bytes) -> bytes:
    return name.encode() + b"\0" + typ.encode() + b"\0" + struct.pack("<i", len(value)) + value


def _header(name: str, width: int, height: int, channels: list[str], chunks: int,
            display: tuple[int, int], multipart: bool) -> bytes:
    def box(w: int, h: int) -> bytes:
        return struct.pack("<4i", 0, 0, w - 1, h - 1)

    chlist = b"".join(c.encode() + b"\0" + struct.pack("<iB3xii", 1, 0, 1, 1)  # HALF
                      for c in sorted(channels)) + b"\0"
    attrs = [
        _attr("channels", "chlist", chlist),
        _attr("compression", "compression", bytes([3])),  # ZIP: 16 scanlines per chunk
        _attr("dataWindow", "box2i", box(width, height)),
        _attr("displayWindow", "box2i", box(*display)),
        _attr("lineOrder", "lineOrder", bytes([0])),
        _attr("pixelAspectRatio", "float", struct.pack("<f", 1.0)),
        _attr("screenWindowCenter", "v2f", struct.pack("<2f", 0.0, 0.0)),
        _attr("screenWindowWidth", "float", struct.pack("<f", 1.0)),
    ]
    if multipart:
        attrs += [_attr("chunkCount", "int", struct.pack("<i", chunks)),
                  _attr("name", "string", name.encode()),
                  _attr("type", "string", b"scanlineimage")]
    return b"".join(attrs) + b"\0"


def _zip_zeros(n_bytes: int) -> bytes:
    """OpenEXR's ZIP of n zero bytes: interleave, delta predictor (+128), zlib."""
    predicted = np.full(n_bytes, 128, np.uint8)
    predicted[0] = 0
    return zlib.compress(predicted.tobytes(), 9)


def _zip_chunk(raw: bytes) -> bytes:
    """OpenEXR's ZIP of a chunk's bytes: even then odd bytes, delta predictor (+128), zlib."""
    b = np.frombuffer(raw, np.uint8)
    t = np.concatenate([b[0::2], b[1::2]]).astype(np.int16)
    t[1:] = (np.diff(t) + 128) & 0xFF
    return zlib.compress(t.astype(np.uint8).tobytes(), 9)


def write_zero_exr(path, parts: list[tuple[str, int, int, list[str]]]) -> int:
    """Write an all-zero half-float scanline EXR with the given (name, width, height, channels)
    parts (multi-part when more than one); returns the file's size in bytes."""
    return write_flat_exr(path, parts, 0.0)


def write_flat_exr(path, parts: list[tuple[str, int, int, list[str]]], value: float) -> int:
    """Write a half-float scanline EXR, every texel of every channel ``value``, with the given
    (name, width, height, channels) parts (multi-part when more than one), ZIP-compressed
    chunk by chunk without holding the image; returns the file's size in bytes."""
    multipart = len(parts) > 1
    lines = 16
    display = (parts[0][1], parts[0][2])
    counts = [(h + lines - 1) // lines for _, _, h, _ in parts]
    heads = b"".join(_header(n, w, h, c, k, display, multipart)
                     for (n, w, h, c), k in zip(parts, counts, strict=True))
    version = 2 | (0x1000 if multipart else 0)
    prefix = b"\x76\x2f\x31\x01" + struct.pack("<I", version) + heads + (b"\0" if multipart
                                                                         else b"")
    pos = len(prefix) + 8 * sum(counts)
    offsets, chunks = [], []
    for idx, (_, w, h, chans) in enumerate(parts):
        cache: dict[int, bytes] = {}
        for y in range(0, h, lines):
            rows = min(lines, h - y)
            if rows not in cache:
                n = rows * len(chans) * w
                cache[rows] = (_zip_zeros(2 * n) if value == 0.0 else
                               _zip_chunk(np.full(n, value, np.float16).tobytes()))
            lead = struct.pack("<iii", idx, y, len(cache[rows])) if multipart else struct.pack(
                "<ii", y, len(cache[rows]))
            offsets.append(pos)
            chunks.append(lead + cache[rows])
            pos += len(chunks[-1])
    with open(path, "wb") as fh:
        fh.write(prefix + struct.pack(f"<{len(offsets)}Q", *offsets) + b"".join(chunks))
    return pos


def exr_second_part_huge(tmp: Path, manifest: str = MANIFEST) -> None:
    """A valid two-part EXR whose second part declares 16384 x 8192 (0.8 MB on disk, 768 MiB
    decoded)."""
    write_zero_exr(tmp / "sky.exr", [("sky", 64, 32, ["B", "G", "R"]),
                                     ("extra", 16384, 8192, ["B", "G", "R"])])
    (tmp / "manifest.toml").write_text(manifest)


def exr_203_channels(tmp: Path, manifest: str = MANIFEST) -> None:
    """A valid EXR of 1024 x 512 with 203 channels (0.4 MB on disk, 203 MiB decoded)."""
    write_zero_exr(tmp / "sky.exr", [("sky", 1024, 512, ["B", "G", "R"] + [
        f"junk.{k:03d}" for k in range(200)])])
    (tmp / "manifest.toml").write_text(manifest)


def exr_8192x4096(tmp: Path, manifest: str = MANIFEST) -> None:
    """A valid single-part EXR of 8192 x 4096, every texel 1.0 (about 200 KiB on disk: its
    ZIP chunks compress a constant; 384 MiB as float32 RGB), four times the renderer's
    texels."""
    write_flat_exr(tmp / "sky.exr", [("sky", 8192, 4096, ["B", "G", "R"])], 1.0)
    (tmp / "manifest.toml").write_text(manifest)


#: attack name -> (fills a bundle directory, a word its rejection reason holds)
#: (``build(directory, manifest)``: ``manifest`` is a valid manifest the attack may use)
ATTACKS: dict[str, tuple[Callable[[Path, str], None], str]] = {
    "fifo-manifest": (fifo_manifest, "FIFO"),
    "dev-zero-manifest": (dev_zero_manifest, "symbolic link"),
    "nested-toml-100k": (nested_toml_100k, "over the cap"),
    "nested-toml": (nested_toml, "deep"),
    "nested-json": (nested_json, "deep"),
    "reason-txt-dir": (reason_txt_directory, "not valid TOML"),
    "huge-manifest-missing-file": (huge_manifest_missing_file, "over the cap"),
    "hdri-link-to-huge-file": (hdri_link_to_huge_file, "symbolic link"),
    "hdri-dev-zero": (hdri_dev_zero, "symbolic link"),
    "hdri-fifo": (hdri_fifo, "FIFO"),
    "hdri-device": (hdri_device, "device" if os.geteuid() == 0 else "FIFO"),
    "hdri-socket": (hdri_socket, "socket"),
    "hdri-hard-link": (hdri_hard_link, "hard link"),
    "hdri-directory": (hdri_directory, "directory"),
    "stray-fifo": (stray_fifo, "FIFO"),
    "too-many-entries": (too_many_entries, "more than"),
    "not-utf8": (not_utf8, "not valid TOML"),
    "exr-second-part-16384x8192": (exr_second_part_huge, "part"),
    "exr-203-channels": (exr_203_channels, "203 channels"),
    "exr-8192x4096": (exr_8192x4096, "exceeds the limit of 2097152 texels"),
}


def drop_attack(inbox: Path, name: str, build: Callable[[Path, str], None],
                manifest: str = MANIFEST) -> Path:
    """Make a directory bundle ``name`` in ``inbox`` as an uploader would: a hidden name that
    ``build`` fills (``manifest``: the valid manifest it may use, e.g. with light newer than
    the active table's, so that the daemon reads its HDRI), then one rename."""
    tmp = inbox / f".{name}"
    tmp.mkdir(parents=True)
    build(tmp, manifest)
    os.rename(tmp, inbox / name)
    return inbox / name


# --------------------------------------------------------------------------- random bundles

_NAME_PARTS = ["sky", "b", "evil\nSTATUS=x", "\x1b[31mred", "ünïcødé", "-rf", "a b",
               "<script>", "%s%n", "x" * 120, "\t", "..", "manifest", "reason.txt",
               "not-utf8-\udcff\udcfe"]  # bytes 0xff 0xfe, as os.fsdecode gives them
_KINDS = ["regular", "regular", "regular", "regular", "fifo", "link-dev-zero",
          "link-missing", "directory", "socket", "hard-link", "giant", "missing"]


def _name(rng: np.random.Generator, k: int) -> str:
    parts = [str(p) for p in rng.choice(_NAME_PARTS, size=int(rng.integers(1, 3)))]
    name = "".join(parts).replace("/", "_") + f"-{k}"
    return os.fsdecode(os.fsencode(name)[-200:]).lstrip(".") or f"n{k}"


def _entry(rng: np.random.Generator, path: Path, kind: str, content: bytes, scratch: Path
           ) -> None:
    """Make ``path`` as ``kind`` (regular files get ``content``)."""
    if kind == "regular":
        path.write_bytes(content)
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "link-dev-zero":
        os.symlink("/dev/zero", path)
    elif kind == "link-missing":
        os.symlink(scratch / "nowhere", path)
    elif kind == "directory":
        path.mkdir()
        if rng.random() < 0.5:
            (path / "inside").write_bytes(content[:100])
    elif kind == "socket":
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            s.bind(str(path))
        except OSError:  # a path too long for sun_path: a FIFO instead
            os.mkfifo(path)
        finally:
            s.close()
    elif kind == "hard-link":
        other = Path(tempfile.mkstemp(dir=scratch)[1])
        other.write_bytes(content)
        os.link(other, path)
    elif kind == "giant":
        with open(path, "wb") as fh:
            fh.truncate(int(rng.integers(1 << 30, 8 << 30)))


def _manifest_naming(hdri: str) -> bytes:
    """The valid manifest naming ``hdri``, a TOML basic string with JSON's escapes (\\uXXXX
    for a control character: valid TOML too)."""
    return MANIFEST.replace('"sky.exr"', json.dumps(hdri)).encode("utf-8", "surrogateescape")


def _manifest_bytes(rng: np.random.Generator, hdri: str) -> bytes:
    text = _manifest_naming(hdri)
    op = 0 if rng.random() < 0.25 else int(rng.integers(1, 9))
    if op == 0:
        return text
    if op == 1:  # bit flips
        b = bytearray(text)
        for i in rng.integers(0, len(b), size=int(rng.integers(1, 6))):
            b[i] ^= 1 << int(rng.integers(0, 8))
        return bytes(b)
    if op == 2:  # truncated
        return text[: int(rng.integers(0, len(text)))]
    if op == 3:  # deep nesting, under or over the cap
        n = int(rng.integers(10, 60_000))
        return text + b"deep = " + b"[" * n + b"]" * n + b"\n"
    if op == 4:  # random bytes
        return rng.bytes(int(rng.integers(0, 4096)))
    if op == 5:  # wrong types and unknown keys
        return text + rng.choice([b"ambient_lux = \"bright\"\n", b"capture = 3\n",
                                  b"checker_raw = \"../../etc/passwd\"\n",
                                  b"sun_lux = 1e400\n", b"[capture]\nx = [[[[[[[[[[1]]]]]]]]]]\n"])
    if op == 6:  # huge
        return text + b"#" + b"x" * int(rng.integers(60_000, 400_000)) + b"\n"
    if op == 7:  # a hostile capture table
        return text + b"[capture]\nsun_clipped = true\nnote = \"\x1b[2J\\nforged\"\n"
    return text.replace(b"2026-06-21T08:00:00+09:00",
                        rng.choice([b"9999-12-31T23:59:59Z", b"0001-01-01T00:00:00Z",
                                    b"\"not a time\"", b"2026-02-30T00:00:00"]))


def random_bundle(rng: np.random.Generator, inbox: Path, k: int, scratch: Path
                  ) -> tuple[str, bool]:
    """Write random bundle number ``k`` into ``inbox`` (a directory bundle, renamed in at the
    end, or a flat one); ``scratch``: a directory outside the inbox for link targets. Returns
    the name it was given and whether the bundle is valid (a regular, unmutated manifest with
    content of its own, the site's EXR as a regular file named .exr, nothing else in it)."""
    name = _name(rng, k)
    directory = rng.random() < 0.7
    hdri = rng.choice(["sky.exr", "sky.hdr", f"{name}.exr"]) if rng.random() < 0.9 \
        else f"{_name(rng, k)}.data"  # never another bundle's name
    hdri_kind = "regular" if rng.random() < 0.5 else str(rng.choice(_KINDS))
    sky = SITE.read_bytes() if rng.random() < 0.7 else rng.bytes(int(rng.integers(0, 200_000)))
    manifest_kind = "regular" if rng.random() < 0.8 else str(rng.choice(_KINDS))
    manifest = _manifest_bytes(rng, str(hdri))
    if rng.random() < 0.15:  # a valid bundle (with an odd name, maybe), which must be taken
        hdri = "sky.exr" if directory else f"{name}.exr"
        hdri_kind = manifest_kind = "regular"
        sky, manifest = SITE.read_bytes(), _manifest_naming(hdri)
    valid = (manifest == _manifest_naming(str(hdri)) and storable(str(hdri)) == str(hdri)
             and manifest_kind == hdri_kind == "regular" and sky == SITE.read_bytes()
             and str(hdri).endswith(".exr"))  # TOML cannot name a file that is not UTF-8
    if valid:
        manifest += f"# bundle {k}\n".encode()  # content of its own: not a duplicate
    if directory:
        tmp = inbox / f".{name}"
        tmp.mkdir()
        if hdri_kind != "missing":
            _entry(rng, tmp / str(hdri), hdri_kind, sky, scratch)
        for j in range(int(rng.integers(0, 4)) if rng.random() < 0.3 and not valid else 0):
            extra = str(rng.choice(["reason.txt", f"extra{j}", "manifest.json", "sub"]))
            if not os.path.lexists(tmp / extra):
                _entry(rng, tmp / extra, str(rng.choice(_KINDS[:-1])), b"x" * 10, scratch)
                valid = False
        mname = "manifest.json" if rng.random() < 0.1 and not valid else "manifest.toml"
        valid = valid and mname == "manifest.toml"
        if manifest_kind != "missing" and not os.path.lexists(tmp / mname):
            _entry(rng, tmp / mname, manifest_kind, manifest, scratch)
        os.rename(tmp, inbox / name)
    else:  # flat: data files first, the manifest last; its files must be named after it
        valid = valid and hdri == f"{name}.exr"
        if hdri_kind != "missing" and not os.path.lexists(inbox / str(hdri)):
            _entry(rng, inbox / str(hdri), hdri_kind, sky, scratch)
        if manifest_kind != "missing":
            _entry(rng, inbox / f"{name}.manifest.toml", manifest_kind, manifest, scratch)
    return name, valid


# --------------------------------------------------------------------------- fuzzing


def _poll(inbox: Inbox) -> list:
    """``inbox.poll()``, failing (AssertionError) when it blocks or raises."""
    out: dict = {}
    t = threading.Thread(target=lambda: out.setdefault("got", inbox.poll()), daemon=True)
    t.start()
    t.join(POLL_LIMIT_S)
    assert not t.is_alive(), "inbox poll blocked"
    assert "got" in out, "inbox poll raised (see the thread's traceback above)"
    return out["got"]


def fuzz_inbox(root: Path, seed: int, bundles: int) -> dict[str, int]:
    """Drop ``bundles`` random bundles into a fresh inbox under ``root``, polling between them
    on a fake clock; archive what is claimed. Returns counts by outcome (journal rows: a
    rejected duplicate has none). AssertionError when a poll blocks or raises, a bundle is left
    neither claimed nor rejected, a valid one is not claimed, a rejected one has no reason.txt
    file, or a restart's
    recover() finds anything to do."""
    rng = np.random.default_rng(seed)
    scratch = root / "scratch"
    scratch.mkdir()
    now = [0.0]
    history = History(root / "state" / "state.db")
    inbox = Inbox(root / "inbox", root / "state", history, settle_s=1.0,
                  incomplete_timeout_s=5.0, clock=lambda: now[0])
    claimed: set[str] = set()
    valid: set[str] = set()
    try:
        for k in range(bundles):
            name, ok = random_bundle(rng, inbox.inbox, k, scratch)
            if ok:
                valid.add(storable(name))
            for b in _poll(inbox):
                inbox.archive_bundle(b, None)
                claimed.add(b.name)
            now[0] += float(rng.choice([0.2, 1.5, 6.0]))
        for _ in range(3):  # past every settle and incomplete timeout
            now[0] += 6.0
            for b in _poll(inbox):
                inbox.archive_bundle(b, None)
                claimed.add(b.name)
        left = [e for e in os.scandir(inbox.inbox) if not e.name.startswith(".")
                and (e.is_dir(follow_symlinks=False) or e.name.endswith(FLAT_SUFFIXES))]
        assert left == [], f"bundles neither claimed nor rejected: {[e.name for e in left]}"
        assert valid <= claimed, f"valid bundles not claimed: {sorted(valid - claimed)}"
        for d in inbox.rejected.iterdir():
            reason = d / "reason.txt"
            assert stat.S_ISREG(reason.lstat().st_mode), f"{d.name}: no reason.txt file"
            assert reason.read_text().strip()
        rejected = len(history.journal("rejected"))
    finally:
        history.close()
    with History(root / "state" / "state.db") as h:  # a restart on the same state
        again = Inbox(root / "inbox", root / "state", h)
        assert again.recover() == []
    assert not any(inbox.processing.iterdir())
    return {"claimed": len(claimed), "valid": len(valid), "rejected": rejected}
