"""The package's public names: each one in ``masknet.__all__`` resolves, lazily."""

from __future__ import annotations

import masknet


def test_every_public_name_resolves():
    for name in masknet.__all__:
        assert getattr(masknet, name) is not None, name
    assert set(masknet.__all__) <= set(dir(masknet))


def test_scene_search_is_exported():
    from masknet import SceneSearch
    from masknet.registration.stages.scene import SceneSearch as defined

    assert SceneSearch is defined and "SceneSearch" in masknet.__all__
    assert SceneSearch(viewpoint=(0.0, 0.0, 0.0)).viewpoint == (0.0, 0.0, 0.0)
