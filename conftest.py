"""Repository-wide pytest set-up (not shipped: the wheel holds only isplat/)."""

import pytest

# isplat/render.py's module example calls render_view with a view object, as the code did before issue #9;
# its rewrite comes with the render core's. Until then that one doctest is an expected failure; once the text
# changes the doctest runs like any other, and this hook can go.
_STALE_RENDER_EXAMPLE = "r.render_view(r.scene.views[0])"


def pytest_collection_modifyitems(items):
    for item in items:
        if item.nodeid == "isplat/render.py::isplat.render" and _STALE_RENDER_EXAMPLE in item.dtest.docstring:
            item.add_marker(pytest.mark.xfail(reason="stale example, rewritten with issue #9's render core",
                                              strict=True))
