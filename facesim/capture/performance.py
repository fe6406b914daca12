"""A captured performance written out: as an ordinary spec (ARKit shapes on a timeline,
the head's and the eyes' angles as pose tracks, at the video's frame times: ``facesim
render`` replays it on any face), as Live Link Face's CSV curves (the export's layout,
facesim.export.rig), and as a plot of its main curves.

A curve is written as the key-frames a straight line through them keeps within
``TOLERANCE`` of every frame's value, so a still stretch is two keys, not one per frame.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import yaml

from ..animation.arkit import ARKIT_52
from ..files import WriteError, atomic_path
from ..physics.muscles import GAZE, GAZE_ANGLE
from .solver import Performance, head_basis, solve
from .subject import subject_turns
from .tracking import Source, open_source, track

#: How far (a weight, degrees for an angle) a written curve may stray from the frames'.
TOLERANCE = {"weight": 0.01, "angle": 0.2}
#: A shape is written if it reaches this weight in some frame.
WRITTEN_FROM = 0.03
#: The curves the plot shows: the jaw, the blinks, the smiles, the brows, and the head.
PLOTTED = ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight", "mouthSmileLeft", "mouthSmileRight", "browInnerUp",
           "mouthPucker", "mouthFunnel")


def capture(source: Source | Path, output: Path, curves: Path | None = None, plot: Path | None = None,
            replace: bool = False, notice=None, progress=None, neutral_at: float = 0.0) -> Performance:
    """Track ``source`` (``open_source``'s, or a video's path), solve it with the subject's
    neutral taken from ``neutral_at`` seconds on, and write the spec (``output``), and the
    CSV curves and the plot when asked, each under a temporary name, read back, renamed.
    ``progress(n)`` is told of each frame tracked, then each solved, twice
    (facesim.capture.subject): three times the source's frames in all. A neutral that
    differs from the video's usual face is said through ``notice``."""
    from ..animation.spec import Spec

    source = source if isinstance(source, Source) else open_source(source, None)
    video = source.path
    tracked = track(source, progress)
    if tracked.several and notice:
        notice(f"{video}: more than one face; following the largest")
    basis = head_basis(Spec(name="capture"))
    performance = solve(tracked, source.fps, basis, str(video), progress, neutral_at)
    # the turns' misreading measured on the subject's own face too: the one the frames fit better
    subject = subject_turns(source, tracked, basis, notice, neutral_at)
    if subject is not None:
        turns, frame = subject
        theirs = solve(tracked, source.fps, basis.turned_as({**basis.turns, **turns}), str(video), progress, neutral_at)
        if np.nanmean(theirs.residual) < np.nanmean(performance.residual):
            performance = dataclasses.replace(theirs, turns_read_on=f"the subject's face, fitted to frame {frame}")
    elif progress:
        progress(len(tracked.landmarks))
    if notice:
        for frames, why in ((performance.missing, "no face found"), (performance.turned, "the face turned past the fit's limit")):
            if frames:
                notice(f"{video}: {why} in {len(frames)} frame{'s' if len(frames) > 1 else ''} ({ranges(frames)}); "
                       "bridged from the frames around them")
        if performance.unsettled:
            first, last = (k / source.fps for k in (performance.neutral[0], performance.neutral[1] + 1))
            notice(f"{video}: expressions are measured from its face at {first:.1f}-{last:.1f} s, which is not its "
                   f"usual face ({performance.unsettled}); it is most usual from {performance.usual_from:.1f} s: if the "
                   "face is not at rest where it is measured from, give --neutral the time of one that is")
    text = spec_yaml(performance, video)
    with atomic_path(output, replace=replace, verify=_verify_spec(performance.frames)) as tmp:
        tmp.write_text(text)
    if curves is not None:
        from ..export.gltf import Clip
        from ..export.rig import _verify_csv, live_link_csv

        clip = Clip(video.stem, performance_weights(performance), performance.head, performance.gaze, performance.fps)
        with atomic_path(curves, replace=replace, verify=_verify_csv(performance.frames)) as tmp:
            tmp.write_text(live_link_csv(clip))
    if plot is not None:
        with atomic_path(plot, replace=replace) as tmp:
            plot_curves(performance, tmp, f"{video.name}: {performance.frames} frames at {performance.fps:g} fps")
    return performance


def ranges(frames: list[int]) -> str:
    """``[3, 4, 5, 9]`` as ``3-5, 9``."""
    out, start = [], frames[0]
    for a, b in zip(frames, frames[1:] + [None]):
        if b != a + 1:
            out.append(f"{start}-{a}" if a > start else f"{a}")
            start = b
    return ", ".join(out)


def performance_weights(performance: Performance) -> np.ndarray:
    """(frames, 52) in ARKit's order: the solved shapes, and the eyes' looks from the
    gaze, each at 1 where the eye turns its gaze control's angle (GAZE_ANGLE)."""
    out = performance.arkit_weights()
    up, down, left, right = (GAZE_ANGLE[GAZE.index(g)] for g in ("gaze_up", "gaze_down", "gaze_left", "gaze_right"))
    for eye, side in ((0, "Left"), (1, "Right")):
        yaw, pitch = performance.gaze[:, eye, 0], performance.gaze[:, eye, 1]
        outward, inward = (left, right) if eye == 0 else (right, left)  # the left eye looks out to the subject's left
        out[:, ARKIT_52.index(f"eyeLookOut{side}")] = np.clip((yaw if eye == 0 else -yaw) / outward, 0, 1)
        out[:, ARKIT_52.index(f"eyeLookIn{side}")] = np.clip((-yaw if eye == 0 else yaw) / inward, 0, 1)
        out[:, ARKIT_52.index(f"eyeLookUp{side}")] = np.clip(pitch / up, 0, 1)
        out[:, ARKIT_52.index(f"eyeLookDown{side}")] = np.clip(-pitch / down, 0, 1)
    return out


def keys(values: np.ndarray, tolerance: float, digits: int) -> list[list[float]]:
    """Key-frames [frame, value] a straight line through which stays within
    ``tolerance`` of every frame's value (greedy: each key as far on as it can be)."""
    values = np.round(np.asarray(values, dtype=float), digits)
    kept, start = [0], 0
    while start < len(values) - 1:
        end = start + 1
        while end + 1 < len(values):
            span = np.arange(start, end + 2)
            line = np.interp(span, [start, end + 1], [values[start], values[end + 1]])
            if np.abs(line - values[span]).max() > tolerance:
                break
            end += 1
        kept.append(end)
        start = end
    return [[int(k), float(values[k])] for k in kept]


def spec_yaml(performance: Performance, video: Path) -> str:
    fps = performance.fps
    timeline = [{"target": name, "interpolation": "linear", "keys": keys(curve, TOLERANCE["weight"], 3)}
                for name, curve in zip(performance.names, performance.weights.T) if curve.max() >= WRITTEN_FROM]
    angles = {"head_yaw": performance.head[:, 0], "head_pitch": performance.head[:, 1], "head_roll": performance.head[:, 2],
              "gaze_yaw": performance.gaze[:, :, 0].mean(axis=1), "gaze_pitch": performance.gaze[:, :, 1].mean(axis=1)}
    pose = [{"target": name, "interpolation": "linear", "keys": keys(np.clip(curve, -90, 90), TOLERANCE["angle"], 2)}
            for name, curve in angles.items() if np.abs(curve).max() >= TOLERANCE["angle"]]
    spec = {"name": video.stem, "frames": performance.frames, "fps": float(fps), "dt": 1.0 / fps, "onset": 0,
            "timeline": timeline, "pose": pose}
    first, last = performance.neutral
    header = (f"# captured by facesim capture from {video.name}: {performance.frames} frames at {fps:g} fps;\n"
              f"# ARKit's shapes and the head's and eyes' angles (degrees), key-framed by frame; the turned\n"
              f"# head's misreading as measured on {performance.turns_read_on} (the landmarks lie\n"
              f"# {np.nanmean(performance.residual) * 10:.2f} mm from the solved face on average);\n"
              f"# expressions measured from the face at {first / fps:.2f}-{(last + 1) / fps:.2f} s\n")
    return header + yaml.safe_dump(spec, sort_keys=False, default_flow_style=None, width=120)


def _verify_spec(frames: int):
    def verify(tmp: Path) -> None:
        from ..animation.spec import load_spec
        from ..errors import InputError

        try:
            spec = load_spec(tmp)
        except InputError as exc:
            raise WriteError(f"the written spec does not read back ({exc})") from None
        if spec.frames != frames:
            raise WriteError(f"the written spec holds {spec.frames} of {frames} frames")

    return verify


def plot_curves(performance: Performance, path: Path, title: str) -> None:
    """The main shapes' weights and the head's angles over time, one above the other."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    seconds = np.arange(performance.frames) / performance.fps
    figure, (shapes, angles) = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True, dpi=100)
    for name in PLOTTED:
        if name in performance.names:
            curve = performance.weights[:, performance.names.index(name)]
            if curve.max() >= WRITTEN_FROM:
                shapes.plot(seconds, curve, label=name, linewidth=1.4)
    shapes.set_ylim(-0.02, 1.02)
    shapes.set_ylabel("weight")
    shapes.legend(loc="upper right", fontsize=8, ncol=2)
    shapes.set_title(title, fontsize=10)
    for k, name in enumerate(("head yaw", "head pitch", "head roll")):
        angles.plot(seconds, performance.head[:, k], label=name, linewidth=1.4)
    angles.plot(seconds, performance.gaze[:, :, 0].mean(axis=1), label="gaze yaw", linewidth=1.0, linestyle="--")
    angles.set_ylabel("degrees")
    angles.set_xlabel("seconds")
    angles.legend(loc="upper right", fontsize=8, ncol=2)
    for frames, colour in ((performance.missing, "0.85"), (performance.turned, "0.7")):
        for k in frames:
            for axis in (shapes, angles):
                axis.axvspan((k - 0.5) / performance.fps, (k + 0.5) / performance.fps, color=colour, linewidth=0)
    figure.tight_layout()
    figure.savefig(path, format="png")
    plt.close(figure)
