"""The ``[content]`` config section of the content feature (:mod:`grassd.daemon.content`):
what the display shows and where it comes from. It lives with the other sections (the
feature imports the configuration, never the other way round).

::

    [content]
    enabled = false               # true: the daemon shows content on the display
    fps = 30                      # frames sent to the controllers per second (1..60)
    hold_s = 1.0                  # a live source gone silent keeps its last frame this long
                                  #   (s, 0..600), then the next source takes over
    map = "nearest_de00"          # RGB picture -> level: "nearest_de00" (the calibration's
                                  #   predicted colour nearest in CIEDE2000), "luminance",
                                  #   or "green" (the picture's green channel)
    normalise = "none"            # before nearest_de00: "none" (sRGB white = the display's
                                  #   white reference) or "lightness" (the picture's L* 0..100
                                  #   stretched onto the display's L* range)
    order = "rows"                # live channels fill the display "rows" or "columns" first,
    serpentine = false            #   every second row (column) backwards when true,
    first = "top-left"            #   starting at this corner (top-left, top-right,
                                  #   bottom-left, bottom-right)
    idle = "pictures/idle.png"    # picture shown when nothing else plays (left out: the
                                  #   display keeps its last frame)
    max_picture_mib = 64          # largest picture or animation file read (MiB)

    [content.sacn]                # E1.31 receiver (UDP)
    enabled = true
    bind = "127.0.0.1"            # address to listen on ("0.0.0.0": every interface)
    port = 5568
    multicast = false             # true: also join the universes' groups 239.255.x.y on the
                                  #   interface of address ``bind`` (the socket then listens
                                  #   on every address: "0.0.0.0")
    universe = 1                  # first universe (1..63999); the display continues in the
    start_channel = 1             #   next ones; the first pixel's channel in the first
                                  #   universe (1..512), later universes start at channel 1
    source_timeout_s = 2.5        # a sender silent this long is gone (E1.31: 2.5 s)
    max_sources = 16              # senders tracked at once; more are dropped and counted

    [content.artnet]              # Art-Net (ArtDmx) receiver (UDP)
    enabled = true
    bind = "127.0.0.1"
    port = 6454
    net = 0                       # first port-address: net (0..127), subnet (0..15),
    subnet = 0                    #   universe (0..15); the display continues in the next
    universe = 0                  #   port-addresses
    start_channel = 1
    source_timeout_s = 2.5
    max_sources = 16

    [[content.playlist]]          # played when no live source sends, in order, looping
    file = "pictures/logo.png"    # PNG, JPEG, animated GIF / APNG (relative: to this file)
    duration_s = 10.0             # how long it stays (an animation loops within it)
    hours = [0, 24]               # local hours ([site] timezone) it may play: start, end
                                  #   (end < start: over midnight)

Each default is written once, on its dataclass below; the bounds with the parser.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from grassd.daemon.core.config import schema

MAPS = ("nearest_de00", "luminance", "green")
NORMALISATIONS = ("none", "lightness")
ORDERS = ("rows", "columns")
CORNERS = ("top-left", "top-right", "bottom-left", "bottom-right")
#: channels of one DMX universe (sACN and Art-Net)
UNIVERSE_CHANNELS = 512


@dataclass(frozen=True)
class SacnConfig:
    """``[content.sacn]``: the E1.31 receiver (address, UDP port, whether it joins the
    universes' multicast groups, first universe, its first channel (1-based), source timeout
    [s], senders tracked at once)."""

    enabled: bool = True
    bind: str = "127.0.0.1"
    port: int = 5568
    multicast: bool = False
    universe: int = 1
    start_channel: int = 1
    source_timeout_s: float = 2.5
    max_sources: int = 16


@dataclass(frozen=True)
class ArtnetConfig:
    """``[content.artnet]``: the Art-Net receiver (address, UDP port, first port-address as
    net/subnet/universe, its first channel (1-based), source timeout [s], senders tracked)."""

    enabled: bool = True
    bind: str = "127.0.0.1"
    port: int = 6454
    net: int = 0
    subnet: int = 0
    universe: int = 0
    start_channel: int = 1
    source_timeout_s: float = 2.5
    max_sources: int = 16

    @property
    def port_address(self) -> int:
        """The 15-bit Art-Net port-address of the first universe (net << 8 | sub << 4 | uni)."""
        return (self.net << 8) | (self.subnet << 4) | self.universe


@dataclass(frozen=True)
class PlaylistEntry:
    """One ``[[content.playlist]]`` entry: a picture or animation ``file``, shown for
    ``duration_s`` seconds, only within the local hours ``start_hour`` .. ``end_hour``."""

    file: Path
    duration_s: float = 10.0
    start_hour: int = 0
    end_hour: int = 24

    def plays_at(self, hour: int) -> bool:
        """Whether the entry may play at local ``hour`` (0..23)."""
        if self.start_hour <= self.end_hour:
            return self.start_hour <= hour < self.end_hour
        return hour >= self.start_hour or hour < self.end_hour  # over midnight


@dataclass(frozen=True)
class ContentConfig:
    """The validated ``[content]`` section (see the module docstring; s, frames/s, MiB)."""

    enabled: bool = False
    fps: int = 30
    hold_s: float = 1.0
    map: str = "nearest_de00"
    normalise: str = "none"
    order: str = "rows"
    serpentine: bool = False
    first: str = "top-left"
    idle: Path | None = None
    max_picture_mib: int = 64
    sacn: SacnConfig = SacnConfig()
    artnet: ArtnetConfig = ArtnetConfig()
    playlist: tuple[PlaylistEntry, ...] = field(default_factory=tuple)


def _hours(v: list[schema.TomlValue]) -> str | None:
    hours = [h for h in v if isinstance(h, int) and not isinstance(h, bool)]
    ok = (len(v) == len(hours) == 2 and 0 <= hours[0] <= 23 and 0 <= hours[1] <= 24
          and hours[0] != hours[1])
    return None if ok else ("must be [start, end] local hours, 0 <= start <= 23, "
                            f"0 <= end <= 24, start != end; got {v!r}")


def _resolve(ctx: schema.Context, value: str) -> Path:
    p = Path(os.path.expandvars(os.path.expanduser(value)))
    return p if p.is_absolute() else ctx.base_dir / p


def _receiver_fields(model: type, universe: schema.Field, **extra: schema.Field
                     ) -> dict[str, schema.Field]:
    F = schema.Field
    return schema.schema(
        model, enabled=F(bool), bind=F(str, check=schema.non_empty),
        port=F(int, check=schema.between(1, 65535)), universe=universe,
        start_channel=F(int, check=schema.between(1, UNIVERSE_CHANNELS)),
        source_timeout_s=F(float, check=schema.between(0.1, 60.0, " s")),
        max_sources=F(int, check=schema.between(1, 256)), **extra)


def parse_content(top: schema.Section) -> ContentConfig | None:
    """Validate the ``[content]`` table of the configuration ``top`` (None when absent); paths
    resolve against the config file's directory. Raises the configuration's error naming the
    key and line."""
    F = schema.Field
    c = top.opt_section("content", schema.schema(
        ContentConfig,
        enabled=F(bool), fps=F(int, check=schema.between(1, 60, " frames/s")),
        hold_s=F(float, check=schema.between(0.0, 600.0, " s")),
        map=F(str, check=schema.one_of(*MAPS)),
        normalise=F(str, check=schema.one_of(*NORMALISATIONS)),
        order=F(str, check=schema.one_of(*ORDERS)), serpentine=F(bool),
        first=F(str, check=schema.one_of(*CORNERS)),
        idle=F(str, check=schema.non_empty, hint="a picture file's path"),
        max_picture_mib=F(int, check=schema.between(1, 1024, " MiB")),
        sacn=F(dict), artnet=F(dict), playlist=F(list, []),
    ))
    if c is None:
        return None
    # a receiver's table left out: the dataclass's default
    sacn = c.get_as("sacn", SacnConfig) if not c.given("sacn") else c.section(
        "sacn", _receiver_fields(SacnConfig, F(int, check=schema.between(1, 63999)),
                                 multicast=F(bool))).fill(SacnConfig)
    artnet = c.get_as("artnet", ArtnetConfig) if not c.given("artnet") else c.section(
        "artnet", _receiver_fields(
            ArtnetConfig, F(int, check=schema.between(0, 15)),
            net=F(int, check=schema.between(0, 127)),
            subnet=F(int, check=schema.between(0, 15)))).fill(ArtnetConfig)
    if sacn.enabled and artnet.enabled and (sacn.bind, sacn.port) == (artnet.bind, artnet.port):
        raise c.error(("artnet", "port"), f"sACN listens on {sacn.bind}:"
                      f"{sacn.port} too; give each receiver its own port")
    playlist = []
    for p in c.sections("playlist", schema.schema(
            PlaylistEntry, file=F(str, check=schema.non_empty),
            duration_s=F(float, check=schema.between(0.1, 86400.0, " s")),
            hours=F(list, [0, 24], check=_hours))):
        start_hour, end_hour = p.get_ints("hours")
        playlist.append(PlaylistEntry(file=_resolve(p.ctx, p.get_str("file")),
                                      duration_s=p.get_float("duration_s"),
                                      start_hour=start_hour, end_hour=end_hour))
    idle = c.get_opt_str("idle")
    return ContentConfig(
        enabled=c.get_bool("enabled"), fps=c.get_int("fps"), hold_s=c.get_float("hold_s"),
        map=c.get_str("map"), normalise=c.get_str("normalise"), order=c.get_str("order"),
        serpentine=c.get_bool("serpentine"), first=c.get_str("first"),
        idle=None if idle is None else _resolve(c.ctx, idle),
        max_picture_mib=c.get_int("max_picture_mib"), sacn=sacn, artnet=artnet,
        playlist=tuple(playlist))
