"""How far each FACS action unit facesim drives, and each of ICT FaceKit's 57 shapes as
the control it stands for, is from ICT's scanned shape for it.

For every action unit of ICT's FACS table that issue 16 names, and every shape of ICT's
(issue 46: a side alone, the jaw's glides, ...; facesim.animation.arkit), simulate it
alone at full intensity on the default head (eased in over 10 frames, held to frame 80),
take the head's face area (ICT vertices 0-9408) at the last frame, and compare its
displacement from the neutral with ICT's shape for it (the sum of its shapes' deltas,
from ``shapes.npz`` beside ICT's README), vertex for vertex:

- direction: the cosine between the two displacement fields, over the vertices that
  either moves by at least 1 mm;
- amplitude: the ratio of their norms over the same vertices, and of the mean
  displacement at the 20 vertices ICT moves most.

Each expression of the library with a FACS prototype is measured the same way at its
apex, against ICT's shapes for the prototype's units, composed and fitted
(facesim.animation.calibration.PROTOTYPES).

Writes the tables to REALISM.md and the atlases (``docs/au_atlas.png``, the action units;
``docs/shape_atlas.png``, ICT's shapes; ``docs/prototype_atlas.png``, the library's
expressions beside their prototypes) (``make realism``). ICT's shapes are measurements here,
never an input to the simulation. Reads ICT's data from ``--ict`` (default
``../shared/ict-facekit``, where the project's build scripts read it).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from facesim.animation.calibration import (  # noqa: E402
    AMPLITUDE,
    COSINE,
    FACE_AREA,
    FRAMES,
    ICT_EXPRESSIONS,
    ICT_ROWS,
    ICT_SHAPES,
    MOVES,
    ON_TOP,
    ONSET,
    PROTOTYPES,
    TONGUE_PAST,
    TOP,
    against_prototype,
    apex_frame,
    compare,
    ict_displacement,
    ict_fields,
    row_control,
    tongue_in_teeth,
    tongue_past_incisors,
)
from facesim.config import HEAD_MUSCLES, HOPPER_MESH  # noqa: E402

#: The compact calibration data the tests read (tests/data/README.md).
CALIBRATION_DATA = ROOT / "tests" / "data" / "ict_shapes.npz"
#: The atlas's frames are rendered at this size and cropped to the face.
ATLAS_SIZE = 512
#: ICT's narrow face area (vertices 0-6705), what the atlas frames.
NARROW_FACE = 6706


def atlas_crop(renderer, figure):
    """A function cropping a frame to the face area's box (with a margin), as the
    renderer frames the head at rest."""
    corners = renderer.project(figure.rest[:NARROW_FACE])
    (left, top), (right, bottom) = corners.min(axis=0), corners.max(axis=0)
    margin = 0.04 * (right - left)
    box = [int(max(v, 0)) for v in (top - margin, bottom + margin, left - margin, right + margin)]
    return lambda image: np.ascontiguousarray(image[box[0]:box[1], box[2]:box[3]])


#: The other faces of issue 16's point 5: ICT's identities 1-5 and the Hopper face, each
#: with the default head's muscles carried over unchanged (no retuning).
OTHER_FACES = [(f"identity {k}", dict(identity=k)) for k in range(1, 6)] + [
    ("Hopper face", dict(mesh=str(HOPPER_MESH), muscles=str(HEAD_MUSCLES)))]
#: Issue 16's bound on the other faces: cosine at least this.
OTHER_COSINE = 0.7


def simulated(row: str, **face):
    """The animation of a row's control (an action unit, or what an ICT shape stands for)
    alone at 1.0 on the default head, or another face (spec fields: ``identity``,
    ``mesh``), eased in and held; None when facesim does not simulate it yet."""
    import facesim
    from facesim.animation.spec import Spec

    try:
        unit = row_control(row)
    except ValueError:
        return None
    under = (ON_TOP[row],) if row in ON_TOP else ()
    units = {u: 1.0 for u in (*under, unit)}
    spec = Spec.model_validate(dict(name=row, frames=FRAMES, onset=ONSET, aus={u: 1.0 for u in units if u.startswith("AU")},
                                    activations={u: 1.0 for u in units if not u.startswith("AU")}, **face))
    return facesim.simulate(spec, stop_on_inversion=False)


def other_face_cosine(au: str, face: dict, theirs: np.ndarray, at_landmarks: np.ndarray) -> tuple[float, int]:
    """Cosine of ``au`` on another face (``face``: its spec fields) against ICT's shape
    carried to it, and the most inverted triangles: on an identity of the head, over its
    face area against ICT's delta (ICT's expression shapes are the same deltas on every
    identity); on a mesh of its own (the Hopper face), at its 468 vertices against ICT's
    displacement at the head's landmarks (the same MediaPipe points). A correction
    (``ON_TOP``) is measured from its base on that face."""
    def moved(animation):
        last = animation.frames - 1
        if "mesh" in face:
            return animation.positions[last]
        return animation.figure.positions(animation.positions[last], animation.jaw_at(last))[:FACE_AREA]

    animation = simulated(au, **face)
    inverted = int(animation.inverted.max())
    base = animation.model.rest_position if "mesh" in face else animation.figure.rest[:FACE_AREA]
    if au in ON_TOP:
        base = moved(simulated(ON_TOP[au], **face))
    return compare(moved(animation) - base, at_landmarks if "mesh" in face else theirs[:FACE_AREA]).cosine, inverted


def draw_atlas(panels: list[tuple[str, str, np.ndarray | None, np.ndarray]], path: Path) -> None:
    """For each unit, facesim | ICT from the front with the same camera and lights, four
    pairs to a row, each labelled with its cosine and amplitude."""
    from PIL import Image, ImageDraw

    width, height = 180, 200
    columns = 4
    rows = -(-len(panels) // columns)
    sheet = Image.new("RGB", (columns * (2 * width + 12), rows * (height + 22)), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for k, (au, label, ours, theirs) in enumerate(panels):
        x0 = (k % columns) * (2 * width + 12)
        y0 = (k // columns) * (height + 22)
        for j, image in enumerate((ours, theirs)):
            if image is None:
                draw.text((x0 + j * width + 40, y0 + 22 + height // 2), label if j == 0 else "no ICT shape", fill=(120, 0, 0))
                continue
            sheet.paste(Image.fromarray(image).resize((width, height), Image.LANCZOS), (x0 + j * width, y0 + 20))
        draw.text((x0 + 4, y0 + 4), f"{au}  facesim | ICT  {label}", fill=(0, 0, 0))
    path.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(path)
    print(f"wrote {path}")


def write_calibration_data(shapes, path: Path) -> None:
    """ICT's 57 expression shapes over the head's face area, as ICT ships them (float16
    deltas, the same names and order), PupilDilate_L/_R over the irises' vertices they
    move (``pupil_rows``, ``pupil_deltas``), and the default head's landmark vertices (what
    scripts/calibrate.py fits the simulated vertices at): every row of the table is a sum
    of these (facesim.animation.calibration.ict_displacement)."""
    from facesim.config import HEAD
    from facesim.face.head import load_head

    head = load_head(HEAD)
    names = [str(n) for n in shapes["expression_names"]]
    assert names == list(ICT_EXPRESSIONS), "ICT's shapes are not the ones facesim's table names"
    path.parent.mkdir(parents=True, exist_ok=True)
    # the pupils' dilation moves nothing on the face: its shapes over the irises it moves
    iris = np.unique(np.concatenate([head.triangles_of(f"M_Iris{side}").ravel() for side in ("Left", "Right")]))
    pupil = np.array([names.index(f"PupilDilate_{side}") for side in "LR"])
    deltas = shapes["expression_deltas"][pupil][:, iris].astype(np.float64)
    rows = iris[(np.linalg.norm(deltas, axis=2) > 1e-6).any(axis=0)]
    np.savez_compressed(path, expression_names=np.array(names), landmark_vertex=head.landmarks,
                        expression_deltas=np.asarray(shapes["expression_deltas"][:, :FACE_AREA], dtype=np.float16),
                        pupil_rows=rows, pupil_deltas=np.asarray(shapes["expression_deltas"][pupil][:, rows], dtype=np.float16))
    print(f"wrote {path}: {len(names)} shapes over {FACE_AREA} face vertices, the pupils' over {len(rows)} iris vertices")


class Table:
    """One table of REALISM.md: each row (an action unit, or one of ICT's shapes)
    simulated on the default head and compared with ICT's shape, its atlas panel, and its
    cosine on the other faces. ``drawing``: the renderer and crop of an earlier table."""

    def __init__(self, shapes, names: list[str], at_landmarks: dict, drawing=None):
        from facesim.renderer.scene import FaceRenderer
        from facesim.renderer.settings import RenderSettings

        self.names, self.rows, self.passed, self.panels = names, [], 0, []
        self.drawing = drawing
        for row in names:
            theirs = ict_displacement(shapes, row) if row in ICT_ROWS else None
            made_of = " + ".join(ICT_ROWS[row]) if row in ICT_ROWS else "(no ICT shape)"
            if row == "tongueOut":
                self.tongue_row(row)
                continue
            animation = simulated(row)
            iris = animation is not None and row.startswith("PupilDilate")  # the irises alone: compared over them
            if not iris and (animation is None or theirs is None or not np.abs(theirs[:FACE_AREA]).max() > 0):
                why = "not simulated yet" if animation is None else "nothing on the face area" if theirs is not None else "no ICT shape"
                control = "" if animation is None else row_control(row)
                self.rows.append(f"| {row} | {made_of} | {control} | {why} | | | | | | |")
                print(self.rows[-1], flush=True)
                self.panels.append((row, why, None, theirs, None))
                continue
            figure = animation.figure
            last = animation.frames - 1
            moved = animation.head_at(last) if iris else figure.positions(animation.positions[last], animation.jaw_at(last))
            inverted = int(animation.inverted.max())
            base = figure.rest
            if row in ON_TOP:  # a correction: compared as the difference from its base, drawn on top of it
                under = simulated(ON_TOP[row])
                base = figure.positions(under.positions[last], under.jaw_at(last))
            area = np.unique(np.concatenate([figure.pupils[0].rows, figure.pupils[1].rows])) if iris else slice(FACE_AREA)
            c = compare((moved - base)[area], theirs[area])
            # gaze: the lids' direction alone (issue 46), as tests/test_realism.py holds them
            ok = (c.cosine >= COSINE if row.startswith("eyeLook") else c.within_bounds) and inverted == 0
            self.passed += ok
            self.rows.append(f"| {row} | {made_of} | {row_control(row)} | {c.cosine:.2f} | {c.amplitude:.2f} | {c.peak:.2f} "
                             f"| {10 * c.ours_peak:.1f} | {10 * c.their_peak:.1f} | {inverted} | {'passes' if ok else 'fails'} |")
            print(self.rows[-1], flush=True)
            if self.drawing is None:
                renderer = FaceRenderer(animation.model.rest_position, animation.model.faces,
                                        RenderSettings(ATLAS_SIZE, ATLAS_SIZE), figure=figure)
                self.drawing = renderer, atlas_crop(renderer, figure), figure
            renderer, crop, _ = self.drawing
            drawn = theirs + (ict_displacement(shapes, ON_TOP[row]) if row in ON_TOP else 0.0)
            self.panels.append((row, f"cos {c.cosine:.2f} amp {c.amplitude:.2f}" + (f" {inverted} inv" if inverted else ""),
                                crop(renderer.render_figure(moved)), drawn, theirs))
        self.other_rows, self.other_passed = [], {name: 0 for name, _ in OTHER_FACES}
        for row, _, ours, _, theirs in self.panels:
            if ours is None or theirs is None or row.startswith("PupilDilate"):  # rigs on every face, nothing on the skin
                continue
            cells = []
            for name, face in OTHER_FACES:
                cosine, inverted = other_face_cosine(row, face, theirs, at_landmarks[row])
                self.other_passed[name] += cosine >= OTHER_COSINE and inverted == 0
                cells.append(f"{cosine:.2f}" + (f" ({inverted} inverted)" if inverted else ""))
            self.other_rows.append(f"| {row} | " + " | ".join(cells) + " |")
            print(self.other_rows[-1], flush=True)

    def tongue_row(self, row: str) -> None:
        """ARKit's tongueOut, which ICT lacks, held to anatomy (issue 46): shown as FACS's
        AU19 (the jaw opened with it), the tip's place in front of the lower incisors, and
        the tongue's points inside a tooth at the last frame and over the jaw's whole range
        at full protrusion."""
        animation = simulated("AU19")
        figure, head, last = animation.figure, animation.model.mesh.head, animation.frames - 1
        moved = animation.head_at(last)
        past = tongue_past_incisors(figure, head, moved)
        inside = tongue_in_teeth(figure, head, moved) + sum(
            tongue_in_teeth(figure, head, figure.positions(animation.model.rest_position, angle, (0.0, 0.0),
                                                           np.r_[np.zeros(6), 1.0, up]))
            for angle in np.radians(np.linspace(0.0, 20.0, 11)) for up in (0.0, 1.0))
        inverted = int(animation.inverted.max())
        ok = past >= TONGUE_PAST and inside == 0 and inverted == 0
        self.passed += ok
        self.rows.append(f"| {row} | (no ICT shape: anatomy) | tongue_out (as AU19, the jaw at 0.5) | tip {past:.2f} cm "
                         f"past the lower incisors (at least {TONGUE_PAST:g}) | {inside} points inside a tooth (none "
                         f"allowed, the jaw from 0 to 20 degrees) | | | | {inverted} | {'passes' if ok else 'fails'} |")
        print(self.rows[-1], flush=True)
        renderer, crop, _ = self.drawing
        self.panels.append((row, f"tip {past:.1f} cm past the incisors", crop(renderer.render_figure(moved)), None, None))

    def table(self) -> str:
        return ("| row | ICT shapes | simulated as | cosine | amplitude | peak ratio | facesim peak (mm) | ICT peak (mm) "
                "| inverted triangles | |\n|---|---|---|---|---|---|---|---|---|---|\n" + "\n".join(self.rows) + "\n")

    def draw_atlas(self, path: Path) -> None:
        renderer, crop, figure = self.drawing
        draw_atlas([(row, label, ours, None if theirs is None else crop(renderer.render_figure(figure.rest + theirs)))
                    for row, label, ours, theirs, _ in self.panels], path)


def prototype_table(shapes, drawing, path: Path) -> str:
    """Each expression of the library that has a FACS prototype (``PROTOTYPES``), at its
    apex on the default head, against ICT's shapes for the prototype's units: composed at
    full intensity, and with each unit's intensity fitted; the atlas ``path`` draws
    facesim's apex beside ICT's composed prototype. Returns the table."""
    import facesim
    from facesim.animation.spec import load_spec

    fields = ict_fields(shapes)
    renderer, crop, figure = drawing
    lines = ["| expression | FACS's prototype | apex frame | composed: cosine | amplitude | fitted: cosine | amplitude "
             "| each unit's fitted intensity |", "|---|---|---|---|---|---|---|---|"]
    panels = []
    for name, units in PROTOTYPES.items():
        animation = facesim.simulate(load_spec(name))
        k = apex_frame(animation)
        moved = animation.figure.positions(animation.positions[k], animation.jaw_at(k))
        measured = against_prototype((moved - animation.figure.rest)[:FACE_AREA], fields, units)
        composed, fitted, weights = measured.composed, measured.fitted, measured.weights
        missing = [u for u in units if u not in ICT_SHAPES]
        shown = " + ".join(units) + (f" ({', '.join(missing)}: no ICT shape)" if missing else "")
        lines.append(f"| {name} | {shown} | {k} | {composed.cosine:.2f} | {composed.amplitude:.2f} | {fitted.cosine:.2f} | "
                     f"{fitted.amplitude:.2f} | " + ", ".join(f"{u} {w:.2f}" for u, w in weights.items()) + " |")
        print(lines[-1], flush=True)
        prototype = sum(ict_displacement(shapes, u) for u in units if u in ICT_SHAPES)
        panels.append((name, f"cos {composed.cosine:.2f}, fitted {fitted.cosine:.2f}", crop(renderer.render_figure(moved)),
                       crop(renderer.render_figure(figure.rest + prototype))))
    draw_atlas(panels, path)
    return "\n".join(lines) + "\n"


#: Issue 47's bounds on a clip's playback from its exported weights, over the face area (mm).
PLAYBACK_RMS, PLAYBACK_LARGEST = 0.5, 2.0


def playback_table() -> tuple[str, int, int]:
    """Each expression of the library on the default head, its frames played back from its
    exported weights (facesim.export.rig): ARKit's 52 alone, as the CSV carries them, and
    with the clip's correctives, as its GLB plays. Returns the table, how many GLBs are
    within the bounds, and how many expressions."""
    import dataclasses

    from facesim.animation.blendshapes import bake, fit_weights, unturned, with_correctives
    from facesim.animation.simulate import simulate
    from facesim.animation.spec import load_spec
    from facesim.export.gltf import rig_glb
    from facesim.export.rig import clip_of

    lines = ["| expression | frames | ARKit's 52 alone (the CSV): RMS / largest, mm | correctives | the GLB: RMS / "
             "largest, mm | the clip adds to the rig, KB | |", "|---|---|---|---|---|---|---|"]
    passed = 0
    specs = sorted((ROOT / "expressions").glob("*.yaml"))
    shapes = bake(load_spec(specs[0]))
    rig = None
    for path in specs:
        animation = simulate(load_spec(path))
        rig = rig or len(rig_glb(shapes, animation.figure))
        frames = [unturned(animation, k) for k in range(animation.frames)]
        alone = fit_weights(shapes, frames)
        extended, played = with_correctives(shapes, frames.__getitem__, animation.frames, alone)
        clip = dataclasses.replace(clip_of(animation, shapes)[0], weights=played.weights)
        adds = (len(rig_glb(extended, animation.figure, clip)) - rig) / 1024
        rms, largest = 10 * played.rms.max(), 10 * played.largest.max()
        within = rms <= PLAYBACK_RMS and largest <= PLAYBACK_LARGEST
        passed += within
        lines.append(f"| {path.stem} | {animation.frames} | {10 * alone.rms.max():.2f} / {10 * alone.largest.max():.2f} | "
                     f"{len(extended.names) - len(shapes.names)} | {rms:.2f} / {largest:.2f} | {adds:.0f} | "
                     f"{'passes' if within else 'fails'} |")
    return "\n".join(lines) + "\n", passed, len(specs)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--ict", type=Path, default=ROOT.parent / "shared" / "ict-facekit")
    parser.add_argument("-o", "--output", type=Path, default=ROOT / "REALISM.md")
    parser.add_argument("--atlas", type=Path, default=ROOT / "docs" / "au_atlas.png")
    parser.add_argument("--shape-atlas", type=Path, default=ROOT / "docs" / "shape_atlas.png")
    parser.add_argument("--prototype-atlas", type=Path, default=ROOT / "docs" / "prototype_atlas.png")
    parser.add_argument("--calibration-data", action="store_true", help=f"write {CALIBRATION_DATA.relative_to(ROOT)} and stop")
    args = parser.parse_args()
    started = time.perf_counter()
    shapes = np.load(args.ict / "shapes.npz")
    if args.calibration_data:
        write_calibration_data(shapes, CALIBRATION_DATA)
        return 0
    shapes_at_landmarks = np.load(CALIBRATION_DATA)
    at_landmarks = {row: field[shapes_at_landmarks["landmark_vertex"]] for row, field in ict_fields(shapes_at_landmarks).items()}
    units = Table(shapes, list(ICT_SHAPES), at_landmarks)
    shapes_table = Table(shapes, [*ICT_EXPRESSIONS, "tongueOut"], at_landmarks, units.drawing)
    units.draw_atlas(args.atlas)
    shapes_table.draw_atlas(args.shape_atlas)
    text = (
        "# Realism: facesim's action units and ICT FaceKit's shapes against ICT's scans\n\n"
        f"Produced by `make realism` (`python scripts/realism.py`) on {time.strftime('%Y-%m-%d')} in "
        f"{time.perf_counter() - started:.0f} s, on the default head. Each action unit alone at full intensity "
        "(eased in over 10 frames, held to frame 80), the face area (ICT vertices 0-9408) at the last frame, "
        "against the sum of ICT's shapes for that unit (ICT's own FACS table; AU26 is half of jawOpen). "
        f"Cosine: of the two displacement fields over the vertices either moves by at least {10 * MOVES:.0f} mm. "
        f"Amplitude: the ratio of their norms there; peak: of the mean displacement at the {TOP} vertices ICT "
        f"moves most. Inverted triangles: the most in any frame of the simulated mesh. Issue 16's bounds: cosine "
        f"at least {COSINE}, amplitude {AMPLITUDE[0]}-{AMPLITUDE[1]}, no inverted triangle. Atlas: "
        "`docs/au_atlas.png`.\n\n"
        f"**{units.passed} of {len(units.names)} action units within the bounds.**\n\n" + units.table() + "\n"
        "## Every shape of ICT's, alone\n\n"
        "Each of ICT FaceKit's 57 expression shapes (ARKit's 52 but tongueOut, with cheekRaiser and PupilDilate), "
        "and ARKit's tongueOut, "
        "simulated as the control it stands for (`facesim shapes`; facesim.animation.arkit): a side alone "
        "(mouthSmile_L is FACS's AU12_L, the muscles of the subject's left), the jaw's glides (AU29, AU30), "
        "against ICT's shape for it, measured as above; mouthClose, which corrects jawOpen, on top of it against "
        "the same on ICT's. The gaze shapes (eyeLook) are held to the lids' direction alone: their amplitude over "
        "the face area is the head's follow spreading a lid landmark's motion (at the landmarks, looking up or down "
        "moves the lids 1.05-1.13 of ICT's), and ICT's eyeballs do not turn. The pupils' dilation moves nothing on "
        "the face area. tongueOut has no ICT shape: it is held to anatomy, shown as FACS's AU19 (the jaw at 0.5), "
        "its tip at least 1 cm in front of the lower incisors' labial face and no point of the tongue (vertex or "
        "triangle centroid) inside a tooth's convex hull, at its last frame and at full protrusion with the jaw "
        "from 0 to 20 degrees, tip raised or not. Atlas: `docs/shape_atlas.png`. mouthClose was short until the jaw turned "
        "where the joints are: about the muscle file's hinge points themselves (the cheeks' contour at the joints' "
        "height, landmarks 234 and 454) the chin swung back more than down, the lower lip dropped less than ICT's "
        "and the sealed lips had less to close (amplitude 0.71). The condyles sit about 1.8 cm deeper, in front of "
        "the ears (the jaw's `hinge_depth`, 0.13 of the points' distance): there, at landmark 152 the chin drops "
        "1.8 -> 2.4 cm (ICT's 2.75) and at 17 the lower lip 2.1 -> 2.5 (ICT's 3.5). Two parts of the figure and "
        "the rig follow it: the shallow lining of the mouth socket turns with the jaw only where the skin does not "
        "carry it (else the lower incisors sank behind it), and sealed, the lips turn back with the skin around "
        "their corners (else the corners' sliver triangles folded with the upper lip rolled in).\n\n"
        f"**{shapes_table.passed} of {len(shapes_table.names)} shapes within the bounds.**\n\n" + shapes_table.table() + "\n"
        "## The same muscles on other faces\n\n"
        "The default head's muscle file carried unchanged (no retuning) to ICT's identities 1-5 (the head's "
        "identity modes, `identity: k`) and to the Hopper face (`meshes/face.obj`, the same MediaPipe topology). "
        "Cosine against ICT's shape carried to that face: on an identity, over its face area against ICT's delta "
        "(ICT's expression shapes are the same deltas on every identity); on the Hopper face, at its 468 vertices "
        f"against ICT's displacement at the head's landmarks. Issue 16's bound: at least {OTHER_COSINE}, no "
        "inverted triangle.\n\n"
        + "".join(f"**{name}: {units.other_passed[name] + shapes_table.other_passed[name]} of "
                  f"{len(units.other_rows) + len(shapes_table.other_rows)}.** " for name, _ in OTHER_FACES) + "\n\n"
        "| row | " + " | ".join(name for name, _ in OTHER_FACES) + " |\n"
        "|---|" + "---|" * len(OTHER_FACES) + "\n" + "\n".join(units.other_rows + shapes_table.other_rows) + "\n"
    )
    prototypes = prototype_table(shapes, units.drawing, args.prototype_atlas)
    text += (
        "\n## The library against FACS's prototypes\n\n"
        "Each expression of the library that has one, at its apex (the last frame at which its muscles are most "
        "activated) on the default head, against ICT's shapes for its FACS prototype's units (as the action units' "
        "rows are composed, AU26 half of jawOpen): the units the expression's file names; for happy and surprise, "
        "which name none, EMFACS's (Ekman, Friesen and Hager 2002); the two compounds as Du, Tao and Martinez (2014) "
        "found them. Composed: every unit at full intensity. Fitted: each unit's intensity (0-1) fitted to the apex "
        "by bounded least squares, the closest ICT's shapes of those units come, and how strongly the face shows "
        "each. The face area, measured as above. No bound is set; the basic six are tested at fitted cosine "
        "0.7 or more (`tests/test_realism.py`). Atlas: facesim's apex beside ICT's composed prototype, "
        "`docs/prototype_atlas.png`.\n\n" + prototypes + "\n"
        "What the fitted intensities say: surprise and fear read closest (0.92); fear shows its raised lids and "
        "brows drawn together but hardly its lid tightener (AU7) or its lips stretched (AU20), and the inner "
        "brows (AU1) little beside the outer (AU2). Angry is the weakest of the six (0.73): ICT has no lip "
        "tightener (AU23) to compose, and the glare's lids and the pressed lips show at half intensity or less. "
        "Happy shows the cheek raiser (AU6) at 0.12 (the thesis's happy has no orbicularis oculi), the "
        "Duchenne smile at 0.50. Disgust raises the upper lip (AU10) at 0.30 where ICT's bares the teeth, and "
        "its corners do not drop (AU15 0.00). Composed at full intensity, sad and the angry disgust fall to "
        "0.47-0.48: the chin raiser (AU17) at full is far more than either shows.\n"
    )
    playback, played_within, expressions = playback_table()
    text += (
        "\n## Played back from the exported rig\n\n"
        "Each expression of the library on the default head, simulated, then fitted onto the rig's 52 ARKit "
        "shapes (each baked by the physics: facesim.animation.blendshapes) by bounded least squares, and played "
        "back from the weights as an engine plays them: the head's face area at every frame against facesim's own "
        "(without the head's pose and the eyes' turn, which travel as joints), the worst frame's RMS and its "
        "largest vertex distance. ARKit's 52 alone is what the CSV (Live Link Face's curves) carries; the GLB "
        "adds the clip's correctives (the fewest principal components of what the 52 miss, each over the fewest "
        "vertices, that bring the face within 0.45 mm RMS and 1.8 mm; 16-bit integers, KHR_mesh_quantization). "
        f"Issue 47's bounds: at most {PLAYBACK_RMS} mm RMS and {PLAYBACK_LARGEST:.0f} mm at most, and a 35-frame "
        "clip adds at most 100 KB to the rig.\n\n"
        f"**{played_within} of {expressions} expressions' GLBs within the bounds.**\n\n" + playback
    )
    args.output.write_text(text)
    print(f"wrote {args.output}: {units.passed} of {len(units.names)} units and {shapes_table.passed} of "
          f"{len(shapes_table.names)} shapes within the bounds; {played_within} of {expressions} clips' playback")
    return 0


if __name__ == "__main__":
    sys.exit(main())
