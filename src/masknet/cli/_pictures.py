"""The pictures of ``masknet register --html``: do they answer "did it work?"

The view opens on the template and the registered source, coloured by each point's
distance to the template on a scale in the clouds' own units; the source as given, the
template's inliers and the rejected source points are one click away. The PNG twin is a
before/after pair of panels. The verdict is written on both.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

__all__ = ["DISTANCE_SCALE", "registration_views"]

# The colour scale ends at this many inlier distances (the fit's 1.5 template spacings):
# points within one inlier distance are in its first third, points beyond it are saturated.
DISTANCE_SCALE = 3.0


def registration_views(
    html: str,
    template: np.ndarray,
    source: np.ndarray,
    moved: np.ndarray,
    result,
    check,
    title: str,
) -> list[tuple[Path, Callable[[Path], object]]]:
    """Writers of the HTML view and its PNG for a registration: template (N, 3), source as
    given (M, 3), moved (M, 3) the registered source, ``result`` the RegistrationResult,
    ``check`` its :func:`~masknet.registration.judge.assessment.assess_registration`."""
    from masknet.geometry.knn import cloud_tree
    from masknet.viewer import view_writers
    from masknet.viz import distance_colours, plot_registration

    distances = cloud_tree(template).query(moved, k=1)[0].reshape(-1)
    limit = DISTANCE_SCALE * float(check.max_correspondence_distance)
    on_object = np.ones(len(moved), bool) if result.source_mask is None else result.source_mask
    caption = (
        f"did it work: {check.verdict}: {check.reason}. Registered points coloured by "
        f"distance to the template, 0 to {limit:.3g} (input units) and beyond."
    )
    layers = {
        "template": template,
        "registered": (moved[on_object], distance_colours(distances[on_object], limit)),
        "source as given": source,
    }
    hidden = ["source as given"]
    if result.mask is not None:
        layers["inliers"] = template[result.mask]
        hidden.append("inliers")
    if result.source_mask is not None:
        layers["rejected"] = moved[~result.source_mask]
        hidden.append("rejected")

    def png(path: Path) -> object:
        return plot_registration(
            template,
            source,
            moved[on_object],
            distances[on_object],
            limit,
            path,
            title,
            f"{check.verdict}: {check.reason}",
        )

    return view_writers(html, layers, title, hidden=tuple(hidden), caption=caption, png=png)
