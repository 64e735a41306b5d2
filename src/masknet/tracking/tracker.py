"""Follow a known object through a stream of frames: :class:`Tracker` and :func:`track`.

Each frame is one of four states:

* ``"found"``: the first frame (without ``init``) ran the full default,
  :func:`masknet.register` (the scene search where the frame is a scene), and the verdict
  (:func:`masknet.assess_registration`) called the pose ``likely correct``;
* ``"tracked"``: the pose came from the last ones. Constant velocity in SE(3) predicts
  it from the last two poses; the frame is cut to the points within the template's radius
  times ``margin`` of the predicted centre (clutter and far surfaces do not pull the fit),
  less the scene's planes there (a floor, a wall: :mod:`masknet.tracking.view`);
  point-to-plane ICP (Open3D) refines the prediction on them; the verdict on those points
  against the template's side the sensor sees (where the ``viewpoint`` is known; a quick
  check of the overlap fit on most frames, the full verdict on every ``FULL_EVERY``-th and
  where the quick one is not clearly right) keeps the track (``likely correct``, or
  ``uncertain`` for at most ``max_uncertain`` frames in a row; then the frame is searched,
  and where no search finds a ``likely correct`` pose the track goes on, ``uncertain``,
  and searches again after as many);
* ``"refound"``: the track slipped (too few points near the prediction, a ``likely
  wrong`` verdict, too many ``uncertain`` ones, ICP carried the pose beyond a frame's
  motion) and a search found the object again, ``likely correct``: ICP from the last
  trusted pose turned about the template's axes, then the full default on the frame cut
  to where the object may have moved since (less its planes), then on the whole frame;
* ``"lost"``: no search found a pose that the verdict calls ``likely correct``; the pose
  is the best guess, never to be trusted (the verdict says how bad). The next frame is
  searched again; where the guess read ``uncertain``, ICP from it first (``tracked`` if
  that reads ``likely correct``).

Every pose is a (4, 4) transform in :func:`masknet.register`'s convention
(:mod:`masknet.geometry.se3`): it maps **frame points into the template frame**,
``template ~= frame_points @ R.T + t`` on the object's points. The object's pose in the
frame (template -> frame, where a robot would grasp it) is its inverse,
:attr:`TrackResult.pose`.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from typing import Any, NamedTuple

import numpy as np

from masknet.errors import MaskNetError
from masknet.geometry.clouds import MIN_POINTS, centroid_radius, median_spacing
from masknet.geometry.prepared_template import PreparedTemplate
from masknet.io_checks import ARRAY_NONFINITE_HINT, check_cloud
from masknet.registration.judge.arbiter import best_judged
from masknet.registration.judge.assessment import Assessment
from masknet.tracking.view import points_near, turned

__all__ = ["STATES", "TrackResult", "Tracker", "points_near", "track"]

STATES = ("found", "tracked", "refound", "lost")
# ICP's pair cut-offs, in template spacings, in turn: the prediction lies within a few
# degrees and per cent of the radius of the pose, a spacing or two at the surface.
ICP_CUTS = (3.0, 1.5)
ICP_ITERATIONS = 30
MAX_POINTS = 4096  # the cut-out frame is brought to this many points (evenly) for ICP
NO_POSE = np.full((4, 4), np.nan)
MARGIN = 1.5  # the frame is cut to this many template radii around the predicted centre
MIN_NEAR = 30  # fewer frame points near the object: it is hidden or out of view
# The scene's plane in that ball (a floor, a wall: tracking.view.background_plane) is
# dropped before ICP and the verdict: the plane that most points beyond the object's reach
# (its radius and a frame's motion, MAX_STEP_SHIFT, from the predicted centre) lie within
# PLANE_BAND template spacings of, found in PLANE_TRIES samples and held by MIN_NEAR of
# them; at most BACKGROUND_PLANES such planes (a floor and a wall behind).
PLANE_BAND = 1.0
PLANE_TRIES = 100
BACKGROUND_PLANES = 2
# A tracked frame's verdict: the quick check (the overlap fit both ways at the pose, the
# verdict's first rule) where it reads CORRECT_FIT or more; the full verdict (its nearest
# fit and slide search, 5-10 times the cost) where it does not, on every FULL_EVERY-th
# tracked frame (a slow drift along a loosely pinned motion), and after a search.
FULL_EVERY = 5
# Frame-to-frame motions beyond these are jumps, not velocities (the sequences move a few
# degrees and per cent of the radius a frame).
MAX_STEP_DEG, MAX_STEP_SHIFT = 10.0, 0.1
# A re-find: ICP from the last trusted pose turned by these angles (degrees) about the
# template's axes, then register on the frame cut to MARGIN plus REFIND_JUMP (a jump) plus
# REFIND_DRIFT a frame since that pose template radii around it, then the whole frame.
NEAR_TURNS_DEG = (0.0, 30.0, 60.0, 90.0, 135.0, 180.0)
REFIND_JUMP, REFIND_DRIFT = 0.2, 0.03


class TrackResult(NamedTuple):
    """One frame's answer.

    frame: the frame's index in the stream (from 0). transform: (4, 4) float64 frame ->
    template (``register``'s convention); NaN where the frame held no points. fitness: the
    share of the judged frame points within the verdict's inlier distance of the template
    at that pose. verdict: ``"likely correct"``, ``"uncertain"`` or ``"likely wrong"``
    (:func:`masknet.assess_registration` on the frame's points near the object); ``""``
    for an empty frame. state: one of :data:`STATES`. seconds: the frame's wall time.
    points: how many frame points the pose was judged on (those near the object, less the
    scene's planes).
    reason: one line saying why the state is what it is.
    """

    frame: int
    transform: np.ndarray
    fitness: float
    verdict: str
    state: str
    seconds: float
    points: int
    reason: str

    @property
    def pose(self) -> np.ndarray:
        """(4, 4) the object's pose in the frame, template -> frame: the inverse of
        :attr:`transform`."""
        return np.linalg.inv(self.transform) if np.isfinite(self.transform).all() else NO_POSE

    @property
    def trusted(self) -> bool:
        """Whether the pose is one to act on: any state but ``"lost"``."""
        return self.state != "lost"


class Tracker:
    """Follow ``template`` through frames given one at a time (a live stream).

    Args:
        template: (N, 3) the object's points, any unit (the frames' unit), or a
            :class:`~masknet.geometry.prepared_template.PreparedTemplate` (prepared here else).
        init: (4, 4) frame -> template transform of the first frame, to track from it
            instead of searching the first frame; None searches.
        seed: the seed of the even subset that ICP sees of a cut-out frame of over 4,096
            points (:func:`~masknet.geometry.sampling.grid_subset`): a stream run twice
            with one seed gives the same poses.
        margin: the frame is cut to the ball of the template's radius (about its
            centroid) times this, around the predicted centre.
        min_points: fewer frame points than this in that ball: the object left the
            view or is hidden, and the full default searches the frame.
        max_uncertain: ``uncertain`` verdicts in a row before a frame is searched (the
            track goes on, ``uncertain``, where the search finds nothing better).
        drop_nonfinite: drop frame rows holding NaN or inf (organised depth frames)
            instead of refusing the frame.
        viewpoint: (3,) the sensor's position in frame coordinates (``(0, 0, 0)`` for depth
            frames in camera coordinates): the searches then place the template as the
            sensor sees it (``register(..., scene=SceneSearch(viewpoint=...))``), which finds
            a full model in a one-sided view more often, and a pose is judged on the
            template's side that the sensor sees at it (its far side is no evidence
            against the pose).
        register_options: other keywords for :func:`masknet.register` where it searches a
            frame.

    Raises:
        MaskNetError: a bad template, or a bad ``init``.
    """

    def __init__(
        self,
        template: np.ndarray,
        *,
        init: np.ndarray | None = None,
        seed: int = 0,
        margin: float = MARGIN,
        min_points: int = MIN_NEAR,
        max_uncertain: int = 3,
        drop_nonfinite: bool = False,
        viewpoint: tuple[float, float, float] | None = None,
        register_options: dict[str, Any] | None = None,
    ) -> None:
        from masknet.geometry.normals import estimate_normals
        from masknet.geometry.open3d_clouds import to_open3d

        given = template.points if isinstance(template, PreparedTemplate) else template
        self.template, _ = check_cloud(given, "template", nonfinite_hint=ARRAY_NONFINITE_HINT)
        # Every search registers against one prepared template: its views are built once.
        self.prepared = template if given is not template else PreparedTemplate(self.template)
        if margin <= 0 or min_points < MIN_POINTS or max_uncertain < 0:
            raise MaskNetError(
                f"margin must be > 0, min_points >= {MIN_POINTS} and max_uncertain >= 0; got "
                f"{margin}, {min_points} and {max_uncertain}"
            )
        self.seed, self.margin, self.min_points = seed, margin, min_points
        self.max_uncertain, self.drop_nonfinite = max_uncertain, drop_nonfinite
        self.register_options = dict(register_options or {})
        self.viewpoint = None if viewpoint is None else np.asarray(viewpoint, dtype=np.float64)
        if viewpoint is not None:
            from masknet.registration.terms.options import SceneSearch

            self.register_options["scene"] = SceneSearch(viewpoint=tuple(viewpoint))
        self.centre = self.template.mean(0)
        self.radius = float(centroid_radius(self.template))
        self.spacing = median_spacing(self.template, sample=2048)
        normals = estimate_normals(self.template)[0]
        self._target = to_open3d(self.template, normals, feature="tracking")
        self._start = None if init is None else _as_pose(init)
        self.reset()

    def reset(self) -> None:
        """Forget the track: the next frame starts over (from ``init`` where given)."""
        self._history: list[np.ndarray] = [] if self._start is None else [self._start]
        self._uncertain = 0
        self._frame = 0
        self._since_full = 0  # tracked frames since the last full verdict
        self._guess = False  # whether the history is a lost frame's uncertain guess
        self._last = None  # the last trusted pose: a later search is a re-find, near it first
        self._gap = 0  # frames since the last trusted pose

    def update(self, frame: np.ndarray, name: str | None = None) -> TrackResult:
        """The object's pose in the next frame (P, 3), any number of points.

        ``name`` (default ``"frame <index>"``) names the frame in errors. An empty frame
        (or one of fewer than 3 points) is ``"lost"``, not an error: sensors drop frames.

        Raises:
            MaskNetError: a frame with NaN or inf rows (without ``drop_nonfinite``), of
                the wrong shape, or in another unit than the template.
        """
        start = time.perf_counter()
        index, self._frame = self._frame, self._frame + 1
        self._gap += 1
        points = self._checked(frame, name or f"frame {index}")
        if points is None:
            self._history = []
            found = _Found(NO_POSE, None, 0, "the frame holds fewer than 3 points")
            state = "lost"
        else:
            state, found = self._step(points)
        seconds = time.perf_counter() - start
        return TrackResult(
            index, found.transform, found.fitness, found.verdict, state, seconds, *found[2:4]
        )

    def _checked(self, frame: np.ndarray, name: str) -> np.ndarray | None:
        from masknet.registration.terms.units import check_units

        array = np.asarray(frame)
        if array.ndim == 2 and array.shape[1] >= 3:
            finite = (
                np.isfinite(array[:, :3]).all(1).sum() if array.dtype.kind == "f" else len(array)
            )
            if len(array) < MIN_POINTS or (self.drop_nonfinite and finite < MIN_POINTS):
                return None
        hint = "pass drop_nonfinite=True (masknet track --drop-nonfinite) to drop them"
        points, _ = check_cloud(array, name, self.drop_nonfinite, hint)
        units = check_units(self.template, points)
        if units.mixed:
            raise MaskNetError(f"{name}: {units.message}")
        return points

    def _step(self, points: np.ndarray) -> tuple[str, _Found]:
        """The state and the answer for a checked frame (P, 3)."""
        why, followed = "", None
        if self._history:
            predicted = _predicted(self._history, self.centre, self.radius)
            # A lost frame's guess is taken up on the full verdict only.
            quick = not self._guess and self._since_full + 1 < FULL_EVERY
            followed = self._follow(points, predicted, quick)
            # ICP carried the pose further than a frame's motion: a jump, or a slide into
            # another fit (a near-symmetric shape turned about its axis); search near.
            jumped = _beyond_step(followed.transform, predicted, self.centre, self.radius)
            holds = not jumped and (
                followed.verdict == "likely correct"
                or (followed.verdict == "uncertain" and self._uncertain < self.max_uncertain)
            )
            if holds:
                return "tracked", self._keep(followed)
            moved = "ICP moved the pose beyond a frame's motion; " if jumped else ""
            why = f"the track slipped ({moved}{followed.reason}); "
        found = self._refind(points, why)
        if found.verdict != "likely correct":
            if followed is not None and followed.verdict == "uncertain" and not self._guess:
                # No better pose anywhere: the track goes on, uncertain, and searches
                # again after max_uncertain more frames.
                self._uncertain = 0
                return "tracked", self._keep(followed)
            # An uncertain best guess is where the next frame looks first: ICP from it
            # that reads likely correct takes the track up; anything less searches again.
            self._history = [found.transform] if found.verdict == "uncertain" else []
            self._uncertain, self._guess = self.max_uncertain, True
            return "lost", found
        state = "refound" if self._last is not None else "found"
        self._history, self._uncertain, self._last = [found.transform], 0, found.transform
        self._gap = 0
        self._since_full, self._guess = 0, False
        return state, found

    def _keep(self, followed: _Found) -> _Found:
        """Take a tracked pose: it joins the history that predicts the next."""
        self._uncertain = 0 if followed.verdict == "likely correct" else self._uncertain + 1
        self._since_full = 0 if followed.full else self._since_full + 1
        self._guess = False
        self._history = [*self._history[-1:], followed.transform]
        self._last, self._gap = followed.transform, 0
        return followed

    def _refind(self, points: np.ndarray, why: str) -> _Found:
        """Search near the last trusted pose (turned, shifted, back from hiding), then all."""
        near = None
        if self._last is not None:
            near = _best(
                self._follow(points, start)
                for start in turned(self._last, self.centre, NEAR_TURNS_DEG)
            )
            near = near._replace(reason=f"{why}searched near the last pose: {near.reason}")
            if near.verdict == "likely correct":
                return near
            around = self._find(points, why, self._last)
            if around.verdict == "likely correct":
                return around
            near = _best([near, around])
        found = self._find(points, why)
        return found if near is None else _best([found, near])  # the better guess, if lost

    def _near(self, points: np.ndarray, transform: np.ndarray, moved: float = 0.0) -> np.ndarray:
        """The frame points (K, 3) within ``margin`` plus ``moved`` template radii of its
        centre placed by ``transform`` (frame -> template), less the scene's planes there
        (:func:`~masknet.tracking.view.without_planes`): what may be the object's."""
        from masknet.tracking.view import without_planes  # noqa: PLC0415

        near = points_near(points, transform, self.centre, (self.margin + moved) * self.radius)
        placed = np.linalg.solve(transform, np.append(self.centre, 1.0))[:3]
        reach, band = self.radius * (1 + MAX_STEP_SHIFT + moved), PLANE_BAND * self.spacing
        return without_planes(
            near, placed, reach, band, BACKGROUND_PLANES, PLANE_TRIES, self.min_points, self.seed
        )

    def _seen(self, transform: np.ndarray) -> np.ndarray:
        """The template points (N', 3) the sensor sees with the object at ``transform``
        (:func:`~masknet.tracking.view.visible_side`); the whole template without a
        ``viewpoint``, or where it sees fewer than ``min_points``."""
        from masknet.tracking.view import visible_side

        if self.viewpoint is None:
            return self.template
        seen = visible_side(self.template, transform, self.viewpoint)
        return self.template[seen] if seen.sum() >= self.min_points else self.template

    def _judged(
        self, near: np.ndarray, transform: np.ndarray, how: str, quick: bool = False
    ) -> _Found:
        """The verdict on the frame points ``near`` (K, 3) the object at ``transform``
        (:func:`masknet.assess_registration`'s, the frame's units checked already) against
        the template's side the sensor sees there (:meth:`_seen`); with ``quick``,
        :func:`_quick_check`'s where it reads the pose right."""
        from masknet.registration.judge.assessment import judge
        from masknet.registration.judge.prepared import prepare_check

        if len(near) < self.min_points:
            reason = f"{how}only {len(near)} frame points near the object"
            unjudged = Assessment("likely wrong", reason, 0.0, 0.0, 0.0, *[np.nan] * 3)
            return _Found(transform, unjudged, len(near), reason)
        prepared = prepare_check(self._seen(transform), near)
        check = _quick_check(prepared, transform) if quick else None
        full = check is None
        if full:
            check = judge(prepared, transform)
        return _Found(transform, check, len(near), how + check.reason, full)

    def _follow(self, points: np.ndarray, predicted: np.ndarray, quick: bool = False) -> _Found:
        """Point-to-plane ICP from ``predicted`` (4, 4) on the frame's points near it;
        ``quick``: the quick check first (:meth:`_judged`)."""
        from masknet.geometry.open3d_clouds import to_open3d
        from masknet.geometry.sampling import grid_subset
        from masknet.registration.solvers.open3d_icp import point_to_plane_at_cuts

        near = self._near(points, predicted)
        if len(near) < self.min_points:
            return self._judged(near, predicted, "")
        even = near[grid_subset(near, MAX_POINTS, self.seed)]
        cuts = tuple(c * self.spacing for c in ICP_CUTS)
        pose, _ = point_to_plane_at_cuts(
            self._target, to_open3d(even, feature="tracking"), predicted, cuts, ICP_ITERATIONS
        )
        # Judged on the points near where ICP ended: a pose that moved keeps its object.
        return self._judged(self._near(points, pose), pose, "", quick)

    def _find(self, points: np.ndarray, why: str, last: np.ndarray | None = None) -> _Found:
        """The full default, :func:`masknet.register`, on the whole frame; with ``last``
        (4, 4), on the frame cut to where the object may have moved since that pose."""
        from masknet.registration.api import register

        searched, options, how = points, self.register_options, "searched: "
        if last is not None:
            searched = self._near(points, last, REFIND_JUMP + REFIND_DRIFT * self._gap)
            options = {k: v for k, v in options.items() if k != "scene"}
            how = "searched around the last pose: "
            if len(searched) < self.min_points:
                return self._judged(searched, last, why + how)
        result = register(self.prepared, searched, **options)
        transform = np.asarray(result.transform, dtype=np.float64)
        return self._judged(self._near(points, transform), transform, why + how)


class _Found(NamedTuple):
    """A pose and its verdict (None for an empty frame), before the state is decided."""

    transform: np.ndarray
    check: Assessment | None
    points: int
    reason: str
    full: bool = True  # the full verdict (False: the quick check's)

    @property
    def verdict(self) -> str:
        """The verdict's words; ``""`` without one."""
        return "" if self.check is None else self.check.verdict

    @property
    def fitness(self) -> float:
        """The verdict's fitness (0 without one)."""
        return 0.0 if self.check is None else self.check.fitness


def _as_pose(value: Any) -> np.ndarray:
    from masknet.registration.terms.validation import as_rigid_transforms

    return np.asarray(as_rigid_transforms(value, 1)[0], dtype=np.float64)


def _quick_check(prepared: Any, transform: np.ndarray) -> Assessment | None:
    """The verdict's first rule alone, for a tracked pose: ``likely correct`` where the
    overlap fit at ``transform`` (4, 4) reads ``CORRECT_FIT`` or more both ways on
    ``prepared`` (:func:`~masknet.registration.judge.assessment.prepare_check`); None (ask the
    full verdict) otherwise. Its nearest fit and slide fields are NaN and 0: not measured."""
    from masknet.geometry.se3 import transform_points
    from masknet.registration.judge.assessment import CORRECT_FIT, NEAR
    from masknet.registration.judge.fit import two_way_fit

    moved = transform_points(transform, prepared.source_points)
    both = two_way_fit(prepared.tree, prepared.template_points, moved, prepared.limit, NEAR)
    (source_fit, fitness, overlap), template_fit = both[0], both[1, 0]
    if source_fit < CORRECT_FIT or template_fit < CORRECT_FIT:
        return None
    worse = min(source_fit, template_fit)
    reason = (
        f"quick check: {worse:.0%} of the overlap fits within {prepared.limit:.3g} (input "
        "units; the worse of the two directions)"
    )
    return Assessment(
        "likely correct", reason, worse, fitness, overlap, np.nan, np.nan, prepared.limit
    )


def _best(candidates: Iterable[_Found]) -> _Found:
    """The judged candidate the arbiter ranks best (its verdict, then its overlap fit)."""
    return best_judged(candidates, lambda c: c.check)


def _predicted(history: list[np.ndarray], centre: np.ndarray, radius: float) -> np.ndarray:
    """The next transform (frame -> template) at constant velocity in SE(3): the last
    frame-to-frame motion of the object, in its own frame, repeated. From transforms T
    (the object's poses P = T^-1), P_next = P_k P_(k-1)^-1 P_k, so
    T_next = T_k T_(k-1)^-1 T_k. With one pose, or after a motion larger than
    :data:`MAX_STEP_DEG` or :data:`MAX_STEP_SHIFT` template radii (of ``centre`` (3,)),
    the last pose: a jump is not a velocity, and repeating it would throw the next
    prediction as far off."""
    if len(history) < 2:
        return history[-1]
    previous, last = history[-2:]
    if _beyond_step(last, previous, centre, radius):
        return last
    return last @ np.linalg.inv(previous) @ last


def _beyond_step(a: np.ndarray, b: np.ndarray, centre: np.ndarray, radius: float) -> bool:
    """Whether transforms ``a`` and ``b`` (4, 4, frame -> template) lie more than a frame's
    motion apart: a turn over :data:`MAX_STEP_DEG`, or the template's ``centre`` (3,)
    placed more than :data:`MAX_STEP_SHIFT` template radii (``radius``) apart."""
    from masknet.geometry.se3 import rotation_angle_deg

    step = a @ np.linalg.inv(b)  # in template coordinates
    point = np.append(centre, 1.0)
    shift = np.linalg.norm(np.linalg.solve(step, point) - point)
    return bool(rotation_angle_deg(step[:3, :3]) > MAX_STEP_DEG or shift > MAX_STEP_SHIFT * radius)


def track(
    template: np.ndarray,
    frames: Iterable[np.ndarray],
    *,
    init: np.ndarray | None = None,
    seed: int = 0,
    **options: Any,
) -> Iterator[TrackResult]:
    """Follow ``template`` (N, 3) through ``frames`` (each (P_f, 3), the template's unit):
    one :class:`TrackResult` per frame, as each is computed (a generator).

    ``init``: (4, 4) frame -> template transform of the first frame (None: the first
    frame is searched with :func:`masknet.register`). ``seed`` and ``options``: those of
    :class:`Tracker` (``margin``, ``min_points``, ``max_uncertain``, ``drop_nonfinite``,
    ``viewpoint``, ``register_options``). Poses are in ``register``'s convention, frame -> template;
    :attr:`TrackResult.pose` is the object's pose in the frame. The states are described
    in :mod:`masknet.tracking.tracker`.

    Example::

        for result in track(template, frames):
            if result.trusted:
                print(result.frame, result.state, result.pose[:3, 3])
    """
    tracker = Tracker(template, init=init, seed=seed, **options)
    for frame in frames:
        yield tracker.update(frame)
