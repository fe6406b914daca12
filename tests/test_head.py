"""ICT FaceKit's head: vendored in ICT's vertex order, identities, the thesis expressions
simulated on it, the jaw carrying the lower teeth, the lids meeting over the eyeballs."""

import dataclasses
import gc
import importlib.util
import itertools
from pathlib import Path

import numpy as np
import pytest
from conftest import THESIS_EXPRESSIONS, spec

from facesim.animation.simulate import simulate
from facesim.config import HEAD, HEAD_MUSCLES
from facesim.errors import InputError
from facesim.face.figure import figure_for
from facesim.face.head import load_head
from facesim.renderer.scene import FaceRenderer
from facesim.renderer.settings import RenderSettings

ROOT = Path(__file__).resolve().parent.parent
#: Vertex positions read off the upstream generic_neutral_mesh.obj (its v lines 1, 5000,
#: 9409, 17040, 21452, 26719): face, face, last face vertex, first tooth, first sclera
#: vertex, last eyelash vertex.
UPSTREAM = {0: (0, -2.48251, 11.8387), 4999: (-0.533943, 0.294245, 9.91105), 9408: (4.1177, -15.4276, 2.93726),
            17039: (2.32055, -2.23823, 5.83703), 21451: (3.28169, 3.59814, 9.64501), 26718: (-5.07248, 2.84276, 8.72492)}


def head_spec(name: str, **changes):
    return spec(name, mesh=HEAD, muscles=HEAD_MUSCLES, **changes)


@pytest.fixture(scope="module")
def head():
    return load_head(HEAD)


def test_vendored_head_keeps_ict_vertex_order(head):
    assert head.vertices.shape == (26719, 3)
    for index, position in UPSTREAM.items():
        np.testing.assert_allclose(head.vertices[index], position, atol=1e-4)
    assert head.parts["face"] == (0, 9408) and head.parts["eyelashes_right"] == (26035, 26718)
    # every part's triangles stay inside its own range (the OBJ's usemtl groups)
    teeth = head.triangles_of("M_Teeth")
    assert teeth.min() >= 17039 and teeth.max() <= 21450


def test_identities_are_distinct_people_of_human_size():
    heads = [load_head(HEAD, seed).vertices for seed in range(10)]
    for a, b in itertools.combinations(heads, 2):
        assert np.sqrt(((a - b) ** 2).sum(axis=1).mean()) >= 0.3
    for seed in range(10):
        corners = load_head(HEAD, seed).landmark_positions[[33, 263]]
        assert 8.0 <= np.linalg.norm(corners[0] - corners[1]) <= 10.5


@pytest.mark.parametrize("name", THESIS_EXPRESSIONS)
def test_thesis_expressions_simulate_on_the_head(name):
    for identity in (None, *range(10)):
        animation = simulate(head_spec(name, identity=identity))  # raises on an inverted triangle
        assert animation.inverted.max() == 0


def test_jaw_turns_the_lower_teeth_and_keeps_the_upper(head):
    animation = simulate(head_spec("happy", activations={"jaw": 1.0}, aus={}, include=[], onset=15))
    figure = figure_for(animation.model)
    angle = animation.jaw_at(animation.frames - 1)[0]
    assert angle == pytest.approx(np.radians(20))
    opened = figure.positions(animation.positions[-1], angle)
    closed = figure.positions(animation.model.rest_position, 0.0)
    teeth = head.part("teeth")
    lower = teeth[head.vertices[teeth, 1] < -4.0]  # only the lower row reaches below the upper
    upper = teeth[head.vertices[teeth, 1] > -1.5]
    from facesim.geometry import axis_rotation

    hinge, axis = figure.jaw_hinge, figure.jaw_axis
    expected = (head.vertices[lower] - hinge) @ axis_rotation(axis, angle).T + hinge
    np.testing.assert_allclose(opened[lower], expected, atol=1e-6)
    assert np.linalg.norm(opened[lower] - closed[lower], axis=1).min() > 1.0
    np.testing.assert_allclose(opened[upper], closed[upper], atol=1e-9)


def test_blink_meets_the_lids_outside_the_eyeballs(head):
    animation = simulate(head_spec("blink"))
    figure = figure_for(animation.model)
    lid = animation.activations[:, animation.muscle_names.index("eyelid_r")]
    closed = [figure.positions(animation.positions[k]) for k in np.flatnonzero(lid == lid.max())]  # held shut
    for upper, lower in ((159, 145), (386, 374)):
        gap = min(x[head.landmarks[upper], 1] - x[head.landmarks[lower], 1] for x in closed)
        assert gap < 0.05  # the lids meet while the blink holds them shut
    for frame in range(animation.frames):
        x = figure.positions(animation.positions[frame])
        for rows, centre, radius in figure.guards:
            assert (np.linalg.norm(x[rows] - centre, axis=1) >= radius - 1e-9).all()


needs_mediapipe = pytest.mark.skipif(importlib.util.find_spec("mediapipe") is None,
                                     reason="MediaPipe not installed (pip install -e '.[photo]')")
#: MediaPipe's mouth corners, outer eye corners, nose tip and chin.
FEATURES = {"mouth corners": [61, 291], "outer eye corners": [33, 263], "nose tip": [1], "chin": [152]}


def test_the_face_framing_fills_the_frame_with_the_face():
    """--framing face (the default on a head) draws the face from brow to chin across the
    frame, where expressions are read; --framing head keeps head and shoulders."""
    neutral = simulate(spec("happy", activations={}, frames=1))
    head = neutral.model.mesh.head
    eyes = head.landmark_positions[[33, 263]]  # outer eye corners
    width = {}
    for framing in ("face", "head"):
        with FaceRenderer.of(neutral, RenderSettings(256, 256, framing=framing)) as renderer:
            width[framing] = np.linalg.norm(np.subtract(*renderer.project(eyes))) / 256
    assert width["face"] > 0.35 and width["face"] > 1.6 * width["head"]
    with pytest.raises(InputError, match=r"--framing: expected one of face, head, got 'torso'"):
        RenderSettings(framing="torso")


#: pyrender's own lit shader, read from its package (a test dependency: facesim draws without it).
PYRENDER_SHADER = Path(importlib.util.find_spec("pyrender").submodule_search_locations[0]) / "shaders" / "mesh.frag"


def _ours_and_pyrenders(animation, settings, arrows=None):
    """The last frame drawn with facesim's lit shader, then with pyrender's own."""
    last = animation.frames - 1
    with FaceRenderer.of(animation, settings) as renderer:
        ours = renderer.frame(animation, last, None if arrows is None else arrows[last])
    with FaceRenderer.of(animation, settings) as renderer:
        renderer.lit_shader = PYRENDER_SHADER
        theirs = renderer.frame(animation, last, None if arrows is None else arrows[last])
        assert any(str(PYRENDER_SHADER) in key[0] for key in renderer._programs)  # pyrender's shader was in use
    return ours.astype(int), theirs.astype(int)


def test_the_lit_shader_draws_what_pyrenders_draws():
    """facesim's lit shader (facesim/shaders/mesh.frag) is pyrender's BRDF without the
    paths facesim does not use: the apex of happy on the head, skin, eyes and teeth, comes
    out the same within one level as with pyrender's own shader."""
    ours, theirs = _ours_and_pyrenders(simulate(spec("happy")), RenderSettings(128, 128))
    assert (theirs != theirs[0, 0]).any(axis=2).mean() > 0.3  # the face fills the frame
    assert np.abs(ours - theirs).max() <= 1


def test_the_lit_shader_draws_lines_as_pyrender_does():
    """Lines have no normals: the lit shader turns them to the camera, as pyrender's does,
    so --show-muscles draws its arrows red (with the normal left undefined they came out
    up to 14 levels off, and black once the lights' loop had a fixed length)."""
    from facesim.export.output import arrows_for

    animation = simulate(spec("surprise"), with_muscle_forces=True)
    ours, theirs = _ours_and_pyrenders(animation, RenderSettings(128, 128, show_muscles=True), arrows_for(animation))
    assert ((ours[..., 0] > 150) & (ours[..., 1] < 80)).sum() > 20
    assert np.abs(ours - theirs).max() <= 1


def test_a_renderer_that_skips_unchanged_uniforms_draws_each_change_of_view(monkeypatch):
    """facesim's programs set a uniform only when its value changes (gl.Program.set):
    turned, lit and posed frame after frame, a renderer draws what one that sets every
    uniform before every part (pyrender's way) draws, and every change shows."""
    import facesim.renderer.gl

    animation = simulate(spec("happy"))
    last = animation.frames - 1
    views = [dict(yaw=0.0, pitch=0.0, light=1.0), dict(yaw=12.0, pitch=-5.0, light=0.6), dict(yaw=0.0, pitch=0.0, light=1.0)]
    gaze = [np.zeros(5), np.array([0.0, 0.0, 0.0, 8.0, 0.0]), np.zeros(5)]
    drawn = {}
    for way in ("remembered", "every uniform"):
        if way == "every uniform":
            remembered = facesim.renderer.gl.Program.set

            def every(program, name, value):
                program._held.clear()
                remembered(program, name, value)

            monkeypatch.setattr(facesim.renderer.gl.Program, "set", every)
        with FaceRenderer.of(animation, RenderSettings(96, 96)) as renderer:
            drawn[way] = []
            for view, pose in zip(views, gaze):
                renderer.view(**view)
                drawn[way].append(renderer.frame(animation, last, pose=pose))
    for ours, theirs in zip(*drawn.values()):
        np.testing.assert_array_equal(ours, theirs)
    first, turned, back = drawn["remembered"]
    assert (first != turned).any() and (first == back).all()


def test_frames_drawn_two_in_flight_are_the_frames_drawn_one_by_one():
    """``FaceRenderer.frames`` computes each frame's vertex arrays on a second thread while
    the frame before it draws, and filters each drawn frame there while the next one
    draws: the head turning, its eyes leading and smiling (look_left), and the skin's
    wireframe with the muscles' arrows over it, and the animation held in one pose, come
    out byte for byte as ``frame`` draws them one after another, every frame in its
    place."""
    from facesim.export.output import arrows_for

    animation = simulate(spec("look_left"), with_muscle_forces=True)
    assert animation.pose is not None
    for settings, arrows in ((RenderSettings(96, 96), None),
                             (RenderSettings(96, 96, wireframe=True, show_muscles=True), arrows_for(animation))):
        with FaceRenderer.of(animation, settings) as renderer:
            one_by_one = [renderer.frame(animation, k, None if arrows is None else arrows[k]) for k in range(animation.frames)]
            in_flight = list(renderer.frames(animation, arrows))
        assert len(in_flight) == animation.frames
        for ours, theirs in zip(in_flight, one_by_one):
            np.testing.assert_array_equal(ours, theirs)
        assert (one_by_one[0] != one_by_one[-1]).any() and (one_by_one[-2] != one_by_one[-1]).any()
    held = np.array([10.0, -4.0, 3.0, -8.0, 5.0])  # one head and gaze pose for every frame, as a dataset's clip holds
    with FaceRenderer.of(animation, RenderSettings(96, 96)) as renderer:
        one_by_one = [renderer.frame(animation, k, pose=held) for k in range(animation.frames)]
        in_flight = list(renderer.frames(animation, pose=held))
    for ours, theirs in zip(in_flight, one_by_one):
        np.testing.assert_array_equal(ours, theirs)


def test_antialiasing_by_the_edge_filter_comes_toward_four_samples_per_pixel():
    """The default antialiasing filters the frame as drawn along its edges
    (render._smooth_edges): happy's apex on the head comes nearer the same frame drawn
    with 4 samples per pixel than the unfiltered frame is (measured at 256²: 40.7 dB
    against 38.7), and only pixels at edges change (3% of the frame)."""
    animation = simulate(spec("happy"))
    frames = {}
    for name, antialias, supersample in (("none", False, False), ("edge", True, False), ("four", True, True)):
        with FaceRenderer.of(animation, RenderSettings(256, 256, antialias=antialias, supersample=supersample)) as renderer:
            frames[name] = renderer.frame(animation, animation.frames - 1)[:, :, :3].astype(float)

    def psnr(a, b):
        return 10 * np.log10(255**2 / ((a - b) ** 2).mean())

    assert psnr(frames["edge"], frames["four"]) > psnr(frames["none"], frames["four"]) + 1.5
    changed = (frames["edge"] != frames["none"]).any(axis=2).mean()
    assert 0.005 < changed < 0.15


@needs_mediapipe
def test_mediapipe_finds_the_default_head_where_its_points_project():
    from facesim.face.photo import detect_landmarks

    neutral = simulate(spec("happy", activations={}, frames=1))  # the default face, at rest
    head = neutral.model.mesh.head
    for camera in ("front", "three-quarter"):
        with FaceRenderer.of(neutral, RenderSettings(512, 512, camera)) as renderer:
            image = renderer.render(neutral.rest)
            found = detect_landmarks(image, camera)  # raises when no face is found
            if camera == "front":
                for name, indices in FEATURES.items():
                    projected = renderer.project(head.landmark_positions[indices])
                    off = np.linalg.norm(found[indices, :2] - projected, axis=1) / 512
                    assert off.max() < 0.02, (name, off)


def _teeth_pixels(animation, frame: int) -> int:
    """Pixels where the teeth show: the frame drawn with 4 samples per pixel (the bounds
    below were measured so) and the teeth painted pure green."""
    figure = animation.figure
    colour = figure.colour.copy()
    colour[animation.model.mesh.head.part("teeth")] = (0.0, 1.0, 0.0, 1.0)
    painted = dataclasses.replace(figure, colour=colour)
    with FaceRenderer(animation.rest, animation.faces, RenderSettings(512, 512, supersample=True), figure=painted) as renderer:
        image = renderer.render(animation.positions[frame], jaw=animation.jaw_at(frame)).astype(int)
    return int(((image[..., 1] > 2 * image[..., 0] + 20) & (image[..., 1] > 2 * image[..., 2] + 20)).sum())


def test_teeth_show_in_the_rendered_mouth_when_the_jaw_opens():
    opened = simulate(spec("happy", activations={"jaw": 1.0}, onset=15))
    assert opened.jaw_at(opened.frames - 1)[0] == pytest.approx(np.radians(20))
    shown = _teeth_pixels(opened, opened.frames - 1)
    assert shown > 300  # about 460 of the 512² frame (the face framed)
    assert _teeth_pixels(opened, 0) < 0.2 * shown  # closed lips hide them but for a line at their seam (73 pixels)


def test_a_renderer_dropped_without_close_does_not_disturb_another():
    """pyrender's finalizer made a dropped renderer's context current to delete it, and
    the garbage collector ran it whenever it liked: once in the middle of another
    renderer's frame, whose GL calls then failed (CI: glBindBuffer, invalid operation).
    facesim's renderer has no finalizer; here the collector runs at every allocation while
    the dropped one is garbage."""
    from facesim.animation.spec import Spec

    animation = simulate(Spec(frames=4, onset=1, aus={"AU12": 1.0}))
    dropped = FaceRenderer.of(animation, RenderSettings(64, 64))
    dropped.frame(animation, 3)
    with FaceRenderer.of(animation, RenderSettings(64, 64)) as renderer:
        expected = renderer.frame(animation, 3)
        dropped.cycle = dropped  # garbage only the collector finds
        del dropped
        threshold = gc.get_threshold()
        gc.set_threshold(1)
        try:
            frame = renderer.frame(animation, 3)
        finally:
            gc.set_threshold(*threshold)
        gc.collect()
        assert np.array_equal(frame, expected)


def test_closing_a_renderer_collects_no_garbage():
    """pyrender's delete ended with a full garbage collection, 0.1 s of every `facesim
    render` at its end: closing a renderer frees its GL objects and context without one."""
    from facesim.animation.spec import Spec

    animation = simulate(Spec(frames=2, onset=1, aus={"AU12": 1.0}))
    renderer = FaceRenderer.of(animation, RenderSettings(32, 32))
    renderer.frame(animation, 1)
    collections = []

    def seen(phase, info):
        if phase == "start":
            collections.append(info["generation"])

    gc.callbacks.append(seen)
    try:
        renderer.close()
    finally:
        gc.callbacks.remove(seen)
    assert 2 not in collections
    renderer.close()  # a second close does nothing


OFFSCREEN = """
import sys
import facesim
from facesim.renderer.scene import FaceRenderer
from facesim.renderer.settings import RenderSettings
animation = facesim.simulate(facesim.load_spec("happy").with_overrides(frames=2))
with FaceRenderer.of(animation, RenderSettings(32, 32)) as renderer:
    drawn = renderer.frame(animation, 1).std() > 0
print(drawn, *(name in sys.modules for name in ("pyrender", "pyglet", "trimesh", "networkx")))
"""


def test_a_renderer_draws_without_pyrender_or_a_window_toolkit():
    """facesim draws with PyOpenGL alone: importing pyrender (its viewer and pyglet,
    trimesh, networkx and SciPy's modules with them) took 0.54-0.61 s of every fresh
    `facesim render` of the head."""
    import subprocess
    import sys

    result = subprocess.run([sys.executable, "-c", OFFSCREEN], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["True", "False", "False", "False", "False"]


def test_closing_one_renderer_leaves_another_drawing():
    """Every EGL renderer of a process shares one display, and pyrender terminated it when
    it deleted a renderer: closing one (`facesim sheet` nests a second face's renderer in
    the first's) ended the other's context."""
    from facesim.animation.spec import Spec

    animation = simulate(Spec(frames=4, onset=1, aus={"AU12": 1.0}))
    with FaceRenderer.of(animation, RenderSettings(64, 64)) as kept:
        expected = kept.frame(animation, 3)
        with FaceRenderer.of(animation, RenderSettings(64, 64)) as inner:
            assert np.array_equal(inner.frame(animation, 3), expected)
        assert np.array_equal(kept.frame(animation, 3), expected)
    with FaceRenderer.of(animation, RenderSettings(64, 64)) as again:  # and the display opens again after the last
        assert np.array_equal(again.frame(animation, 3), expected)


def _brow_row(image: np.ndarray, column: int, rows: slice) -> int:
    """The darkest row of a brow's column band (5 pixels wide) within ``rows``."""
    luminance = image[rows, column - 2:column + 3, :3].astype(float).mean(axis=(1, 2))
    return rows.start + int(np.argmin(luminance))


def test_the_clay_head_has_eyebrows_that_ride_the_skin():
    """A bald clay head's brows read only from their colour (facesim.face.figure._brow_colour):
    they show darker than the forehead, and AU1 + AU2 raise them on the picture as far as
    the skin under them rises."""
    raised = simulate(spec("happy", activations={}, aus={"AU1": 1.0, "AU2": 1.0}))
    head = raised.model.mesh.head
    brow = head.landmark_positions[[105, 52]].mean(axis=0)  # the right brow's middle, between its contours
    forehead = head.landmark_positions[151]
    with FaceRenderer.of(raised, RenderSettings(512, 512)) as renderer:
        rest, apex = renderer.render(raised.rest), renderer.render(raised.positions[-1])
        (bx, by), (fx, fy) = renderer.project(np.array([brow, forehead])).round().astype(int)
        lift = raised.positions[-1] - raised.rest
        brow_vertex = int(np.argmin(np.linalg.norm(raised.rest - brow, axis=1)))
        risen = renderer.project(np.array([brow + lift[brow_vertex]]))[0, 1]
    skin = rest[fy - 2:fy + 3, fx - 2:fx + 3, :3].astype(float).mean()
    assert rest[by - 2:by + 3, bx - 2:bx + 3, :3].astype(float).mean() < 0.75 * skin
    band = slice(by - 40, by + 20)
    before, after = _brow_row(rest, bx, band), _brow_row(apex, bx, band)
    assert abs(before - by) <= 4  # the dark band lies where the brow's points project
    assert after < before - 3  # and it rises with the skin: about as far as the brow's vertex
    assert abs((before - after) - (by - risen)) <= 4
