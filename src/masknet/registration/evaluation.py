"""Moved: :func:`evaluate_registration` is in :mod:`masknet.registration.judge.fit`, the one fit
module (also importable as ``masknet.evaluate_registration``)."""

from masknet._moved import moved_names

__getattr__ = moved_names(
    __name__,
    {
        name: "masknet.registration.judge.fit"
        for name in (
            "DEFAULT_SPACINGS",
            "RegistrationQuality",
            "evaluate_registration",
            "given_cut",
            "inlier_fit",
        )
    },
)
