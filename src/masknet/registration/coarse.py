"""Moved: the robust pipeline's search is :mod:`masknet.registration.stages.search`
(the robust algorithm and its plumbing sit together in :mod:`masknet.registration.stages.robust`)."""

from masknet._moved import moved_names

__getattr__ = moved_names(
    __name__,
    {
        **{
            name: "masknet.registration.stages.search"
            for name in ("REFINE_TOLERANCE", "coarse_to_fine")
        },
        "check_points": "masknet.registration.judge.prepared",
    },
)
