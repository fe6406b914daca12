"""Static pictures: the muscle map (the thesis's figures 3.2 and 3.8) and the expression
sheet (figure 3.12), drawn with matplotlib."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np

from ..files import atomic_path


def _front_view(model, backend: str) -> tuple[np.ndarray | None, np.ndarray]:
    """What the muscle map is drawn over: for a head (facesim.face.figure), its front render and
    where each simulated vertex shows on it, centred, y up, in pixels; for a mask, nothing
    and its own x, y."""
    from ..face.figure import figure_for
    figure = figure_for(model)
    if figure is None:
        return None, model.rest_position[:, :2]
    from ..renderer.scene import FaceRenderer
    from ..renderer.settings import RenderSettings
    settings = RenderSettings(900, 1000)
    with FaceRenderer(model.rest_position, model.faces, settings, backend, figure) as renderer:
        image = renderer.render(model.rest_position)
        pixels = renderer.project(figure.rest[figure.anchor])
    return image, np.column_stack([pixels[:, 0] - settings.width / 2, settings.height / 2 - pixels[:, 1]])


def plot_muscles(model, regions: list[np.ndarray], path: Path, backend: str = "auto") -> None:
    """The face from the front (a head rendered, a mask as its mesh), every muscle an
    arrow from insertion to attachment, its region of influence (``regions``, the mesh's
    vertices of each: facesim.physics.model.muscle_regions) shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    image, x = _front_view(model, backend)
    names = model.muscles.names
    fig, ax = plt.subplots(figsize=(9, 10))
    if image is not None:
        h, w = image.shape[:2]
        ax.imshow(image, extent=(-w / 2, w / 2, -h / 2, h / 2))
    ax.triplot(x[:, 0], x[:, 1], model.faces, color="0.75" if image is None else "white", lw=0.4,
               alpha=1.0 if image is None else 0.35)
    cmap = plt.get_cmap("tab20")
    families = sorted({n.removesuffix("_l").removesuffix("_r") for n in names})
    for m, region in enumerate(regions):
        family = names[m].removesuffix("_l").removesuffix("_r")
        colour = cmap(families.index(family) % 20)
        ax.scatter(x[region, 0], x[region, 1], s=28, color=colour, alpha=0.35, lw=0)
        ring = model.muscles.ring[m]
        if len(ring):  # a sphincter: its ring, closed, in order around its middle
            middle = x[ring, :2].mean(axis=0)
            ring = ring[np.argsort(np.arctan2(x[ring, 1] - middle[1], x[ring, 0] - middle[0]))]
            loop = x[np.append(ring, ring[0])]
            ax.plot(loop[:, 0], loop[:, 1], color=colour, lw=1.8, ls="--")
            label_at = x[ring[np.argmin(x[ring, 0])]]
        else:
            o, i = model.muscles.attachment[m], model.muscles.insertion[m]
            ax.annotate("", xy=x[o, :2], xytext=x[i, :2],
                        arrowprops=dict(arrowstyle="-|>", color=colour, lw=1.8, shrinkA=0, shrinkB=0))
            label_at = x[o]
        if not names[m].endswith("_l"):
            ax.text(label_at[0], label_at[1], " " + family.replace("_", " "), fontsize=6.5, color="0.15",
                    ha="right" if label_at[0] < 0 else "left", va="center")
    pinned = model.pinned
    ax.scatter(x[pinned, 0], x[pinned, 1], s=8, color="k", marker="s", label="pinned")
    if image is not None:  # the face, not the whole head
        low, high = x.min(axis=0), x.max(axis=0)
        margin = 0.08 * (high - low)
        ax.set_xlim(low[0] - margin[0], high[0] + margin[0])
        ax.set_ylim(low[1] - margin[1], high[1] + margin[1])
    ax.set_aspect("equal")
    ax.set_axis_off()
    ax.set_title(f"{model.muscle_count} muscles: arrows from insertion to attachment, sphincter rings dashed, regions shaded")
    ax.legend(loc="lower right", fontsize=8)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight")
    plt.close(fig)


def contact_sheet(images: list[np.ndarray], labels: list[str], path: Path, columns: int = 3, replace: bool = True) -> None:
    """Images in a labelled grid."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = -(-len(images) // columns)
    h, w = images[0].shape[:2]
    fig, axes = plt.subplots(rows, columns, figsize=(columns * w / 120, rows * (h / 120 + 0.35)))
    for ax in np.atleast_1d(axes).ravel():
        ax.set_axis_off()
    for ax, image, label in zip(np.atleast_1d(axes).ravel(), images, labels):
        ax.imshow(image)
        ax.set_title(textwrap.fill(label, 22), fontsize=12 if len(label) <= 15 else 9)
    fig.tight_layout()
    with atomic_path(path, replace=replace) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)
