"""The studio's pace: how much work each step of a job takes, set by the latency goals (first
characteristic within 150 ms, first image of the pixel within 300 ms, converged within 1 s,
warm, 2 cores). Camera paths a replicate and replicates a round, the renderer's launch sizes
where no interrupt stops a launch, and the pixel image's sizes and passes, each with the reason
for it; the measurements that chose them are in docs/studio.md ("The pace's numbers").
:mod:`grassd.daemon.studio.session` runs a job's steps with them.
"""

from __future__ import annotations

#: Camera paths per replicate in the studio: small replicates, so the first round is quick and
#: later rounds add just what the target needs (the same paths per length as the daemon's
#: 4096 x 8 after 32 replicates).
STUDIO_SAMPLES: int = 1024
#: Camera paths per replicate when the green blades splay. The renderer then traces a path
#: at nearly every length (the blades' planes turn with the length; it keeps only the rays
#: clear of every green blade) instead of about 5 of the 11, so a replicate costs a few times
#: as much. A quarter of the paths a replicate and 4x the replicates a round
#: (:func:`studio_pace`) keep the first round's time and each round's paths.
SPLAY_SAMPLES: int = 256
#: Fewest camera paths a renderer launch takes in a studio without interrupts (in the server's
#: process, in tests; the simulator process launches whole rounds,
#: :attr:`~grassd.daemon.studio.session.Studio.interrupts`): a round of 8 x 1024 paths goes in
#: launches of 2 replicates, and the run checks for a newer input between them, so an input
#: that comes in while a round computes waits for one launch (about a quarter of the round),
#: not the whole round. The numbers do not depend on how the replicates are split into
#: launches.
STUDIO_LAUNCH_PATHS: int = 2048
#: Most camera paths a launch takes in a studio without interrupts, scaled like the replicates
#: (:func:`studio_pace`: a quarter where the blades splay): a larger replicate (a low sun's 8192
#: paths, :class:`~grassd.daemon.core.calibration.simulation.LargerReplicates`) goes in
#: launches of a share of its paths (the numbers change by float64 rounding only), and a
#: splayed round in launches of 4 replicates, so a new input waits for one launch, not the
#: round. Larger launches cost less per path (the last task of a launch leaves a core idle,
#: the threads' start and stop take CPU time, and a core that idled between launches may join
#: late); that is why the simulator process, where a newer input stops the launch in flight,
#: launches whole rounds. (A round without splay goes in launches of 2 replicates, a quarter
#: of its 8, whatever this cap.)
STUDIO_MAX_LAUNCH_PATHS: int = 4096
#: Replicates of the first round (their spread is the first error band).
FIRST_REPLICATES: int = 4
#: Most replicates a characteristic takes before it is sent as it is.
MAX_REPLICATES: int = 256
#: Most replicates a later round adds: a round then stays short (about 0.1 s for 11 lengths),
#: so a new input waits little for the round in flight.
ROUND_REPLICATES: int = 8
#: (width px, paths per image pixel) of the pixel's first image, and of each refining pass
#: (the preview kernel rounds the paths up to a square: 2 or 4 cost the same). The first image
#: is drawn between the characteristic's first and second rounds, so its time adds to every
#: converged time: one path per pixel, a third of the time of four (its noise is gone with the
#: refining passes after everything else).
FIRST_IMAGE: tuple[int, int] = (96, 1)
REFINE_IMAGE: tuple[int, int] = (192, 1)
#: Refining passes of the pixel's image after everything else (24 paths per image pixel).
REFINE_PASSES: int = 24
#: Refining passes the image of the condition pinned as B gets before A's image is refined (8
#: paths per image pixel, about 1 s on 2 cores): B was pinned as it was, often with its first
#: image only, which stayed at half the width and one path a pixel.
PINNED_PASSES: int = 8


def studio_pace(splay_deg: float, n_lengths: int) -> tuple[int, int, int]:
    """(camera paths a replicate, most replicates a later round adds, most replicates in all)
    of the studio's characteristic of ``n_lengths`` lengths, green blades splayed by
    ``splay_deg`` (deg): :data:`STUDIO_SAMPLES`, :data:`ROUND_REPLICATES`,
    :data:`MAX_REPLICATES` without splay (or with 2 lengths or fewer); with it,
    :data:`SPLAY_SAMPLES` a replicate and the replicates scaled to the same paths."""
    if splay_deg <= 0 or n_lengths <= 2:
        return STUDIO_SAMPLES, ROUND_REPLICATES, MAX_REPLICATES
    scale = STUDIO_SAMPLES // SPLAY_SAMPLES
    return SPLAY_SAMPLES, ROUND_REPLICATES * scale, MAX_REPLICATES * scale
