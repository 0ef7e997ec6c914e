"""``grassd demo``: the colour pipeline on a built-in example characteristic (interim).

Until the renderer is wired in, the demo synthesises the linear Rec.709 colour of one grass
pixel at each green-grass length from a simple, documented model, and runs it through the real
calib pipeline: exposure normalisation with a virtual 18 % grey card, Rec.709 -> ProPhoto
(Bradford) -> CIELAB (D50) -> OGCD -> monotone fit -> 8-bit length table, then prints the
table summary (R^2 before/after, range, some entries).

Example model (numbers are plausible illustrations, not measurements):

* Albedos, given as sRGB 8-bit values like the paper's colour-measuring tool reports them and
  linearised with the sRGB transfer function: fixed yellow grass (200, 176, 92), a dry-straw
  yellow; growing green grass (58, 112, 46), an artificial-turf green.
* Pixel geometry from the paper: a 33.5 mm square top with three 5.7 mm slits, so at most
  3 x 5.7 / 33.5 = 51 % of the top shows green grass when seen from above; from the reference
  viewpoint the yellow blades (10 mm tall) hide the green ones until they grow past them.
* Green coverage S-curve: ``c(x) = c_max / (1 + exp(-(x - 11 mm) / 1.6 mm))`` with
  c_max = 0.51, i.e. half-visible 1 mm above the yellow blade tips.
* Pixel colour: linear mix ``(1 - c) * yellow + c * green`` under a neutral light whose level
  does not matter (exposure is normalised on the grey card rendered under the same light).
* Optional Monte Carlo-like noise (``--noise``, relative per channel) to exercise the fit.
"""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np
from numpy.typing import NDArray

from grassd.calib.characteristic import Characteristic, fit_characteristic
from grassd.calib.colour_spaces import M_REC709_TO_XYZ
from grassd.calib.exposure import normalise_exposure
from grassd.calib.length_table import build_length_table
from grassd.rigs import FIRMWARE_BACKENDS

YELLOW_SRGB8 = (200, 176, 92)
GREEN_SRGB8 = (58, 112, 46)
SLIT_FRACTION = 3 * 5.7 / 33.5
COVERAGE_MID_MM = 11.0
COVERAGE_WIDTH_MM = 1.6
LIGHT_LEVEL = 3.7  # arbitrary scene-linear illumination; removed by exposure normalisation


def srgb8_to_linear(srgb8: tuple[int, int, int]) -> NDArray[np.float64]:
    """sRGB 8-bit -> linear Rec.709 (IEC 61966-2-1 transfer function)."""
    v = np.asarray(srgb8, dtype=np.float64) / 255.0
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def green_coverage(lengths_mm: NDArray[np.float64]) -> NDArray[np.float64]:
    """Visible green fraction of the pixel top vs green-grass length (logistic S-curve)."""
    return SLIT_FRACTION / (1.0 + np.exp(-(lengths_mm - COVERAGE_MID_MM) / COVERAGE_WIDTH_MM))


def example_pixel_rgb(lengths_mm: NDArray[np.float64]) -> NDArray[np.float64]:
    """Linear Rec.709 colour (n, 3) of the example grass pixel at each length (mm)."""
    c = green_coverage(np.asarray(lengths_mm, dtype=np.float64))[:, None]
    mix = (1.0 - c) * srgb8_to_linear(YELLOW_SRGB8) + c * srgb8_to_linear(GREEN_SRGB8)
    return LIGHT_LEVEL * mix


@click.command("demo")
@click.option(
    "--example-curve",
    is_flag=True,
    help="Only run the colour pipeline on the built-in synthetic characteristic (no daemon, "
    "no renderer).",
)
@click.option(
    "--workdir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Where the daemon demo keeps its state (default: a new temporary directory).",
)
@click.option(
    "--lengths",
    "n_lengths",
    default=21,
    show_default=True,
    type=click.IntRange(3, 1000),
    help="Number of green-grass lengths sampled from 0 to 20 mm.",
)
@click.option(
    "--noise",
    default=0.0,
    show_default=True,
    type=click.FloatRange(0.0, 0.5),
    help="Relative per-channel noise added to the pixel colour (Monte Carlo-like).",
)
@click.option("--seed", default=1, show_default=True, type=int, help="Noise seed.")
@click.option("--full", is_flag=True, help="Print all 256 table entries.")
@click.option(
    "--firmware",
    type=click.Choice(FIRMWARE_BACKENDS),
    default=FIRMWARE_BACKENDS[0],
    show_default=True,
    help="Simulated controllers: the Python model, or the C firmware (posix process, QEMU).",
)
def demo(
    example_curve: bool,
    workdir: Path | None,
    n_lengths: int,
    noise: float,
    seed: int,
    full: bool,
    firmware: str,
) -> None:
    """The main job on the embedded default site, against simulated hardware.

    Starts ``grassd run --simulate-hardware`` (two simulated controllers on pseudo-terminals, a
    Modbus lux sensor on 127.0.0.1), drops a light bundle built from the bundled CC0 HDRI, waits
    until the new table is active on every controller, then prints the status and where the
    report and plot are. With ``--example-curve``: only the colour pipeline on a built-in
    synthetic characteristic, printing the 8-bit table.
    """
    if not example_curve:
        from grassd.daemon.cli.demo_daemon import run_demo

        run_demo(workdir, echo=click.echo, firmware=firmware)
        return
    lengths = np.linspace(0.0, 20.0, n_lengths)
    rgb = example_pixel_rgb(lengths)
    stderr = None
    if noise > 0:
        rng = np.random.default_rng(seed)
        stderr = noise * rgb
        rgb = np.clip(rgb + stderr * rng.standard_normal(rgb.shape), 0.0, None)
    grey_card = LIGHT_LEVEL * 0.18 * np.ones(3)  # the virtual 18 % grey card, same light
    rgb_n = normalise_exposure(rgb, grey_card, space="rec709")
    se_n = None if stderr is None else normalise_exposure(stderr, grey_card, space="rec709")
    char = Characteristic.from_rgb(lengths, rgb_n, se_n, space="rec709")
    fit = fit_characteristic(char)
    table = build_length_table(fit)

    y_grey = float((rgb_n @ M_REC709_TO_XYZ[1])[0])
    click.echo(
        "grassd demo: built-in example characteristic (synthetic, see grassd.daemon.cli.demo)"
    )
    click.echo(
        f"  yellow sRGB {YELLOW_SRGB8}, green sRGB {GREEN_SRGB8}, "
        f"max green coverage {SLIT_FRACTION:.2f}, S-curve mid {COVERAGE_MID_MM} mm, "
        f"width {COVERAGE_WIDTH_MM} mm, noise {noise:g}"
    )
    click.echo(
        f"  {n_lengths} lengths 0-20 mm; pixel Y at 0 mm after grey-card normalisation {y_grey:.3f}"
    )
    click.echo(
        "  OGCD (dE00) at "
        + ", ".join(
            f"{x:g} mm: {o:.2f}"
            for x, o in zip(
                lengths[:: max(1, n_lengths // 5)],
                char.ogcd[:: max(1, n_lengths // 5)],
                strict=True,
            )
        )
    )
    click.echo(
        f"8-bit length table: OGCD range {table.ogcd_range:.2f} dE00, "
        f"R^2 before {table.r2_before:.4f} -> after {table.r2_after:.6f}, "
        f"max level error {table.max_level_error:.4f} dE00"
    )
    levels = range(256) if full else (0, 1, 2, 32, 64, 96, 128, 160, 192, 224, 253, 254, 255)
    click.echo(
        "  level -> length (um): " + ", ".join(f"{v}: {int(table.lengths_um[v])}" for v in levels)
    )
