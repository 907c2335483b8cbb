"""three.js for the HTML viewer, taken at run time from the copy the installed trimesh ships.

trimesh (a declared dependency) bundles three.js (r140, MIT licence) with its
``TrackballControls`` and ``GLTFLoader`` in the template of its notebook viewer
(``trimesh/resources/templates/viewer.zip``, package data of trimesh, used by
:func:`trimesh.viewer.notebook.scene_to_html`), so that viewer works offline. Its own viewer
shows a mesh and nothing else (no readout, no toggles), so :mod:`qifreport.reports.html`
uses only the library: :func:`three_js` returns three.js and its TrackballControls from that
script, without the GLTF loader and trimesh's viewer code that follow them. Nothing of
three.js is kept in this repository.

The template is not a documented interface of trimesh: when a trimesh release lays it out
otherwise, :func:`three_js` raises :class:`ThreeJsUnavailable` naming the version (nothing
is written; the tests run it), rather than embedding something else.
"""

from __future__ import annotations

import functools
import io
import zipfile
from importlib import resources

__all__ = ["ThreeJsUnavailable", "three_js", "three_js_origin"]

#: trimesh's packed viewer template and the member holding the page
_ARCHIVE, _MEMBER = "resources/templates/viewer.zip", "viewer.html.template"
#: the end of the TrackballControls module, which follows three.js in the template's script
_CONTROLS_END = "THREE.TrackballControls=TrackballControls;})();"


class ThreeJsUnavailable(RuntimeError):
    """The installed trimesh has no three.js bundle laid out as expected."""


def three_js_origin() -> str:
    """Where :func:`three_js` comes from, e.g. ``"trimesh 4.5.3"`` (for the page's footer)."""
    import trimesh

    return f"trimesh {trimesh.__version__}"


@functools.lru_cache(maxsize=1)
def three_js() -> str:
    """The JavaScript of three.js and its TrackballControls (one classic script that
    defines the global ``THREE``, with the library's licence header), about 640 kB.

    Raises
    ------
    ThreeJsUnavailable
        The installed trimesh ships no such bundle.
    """
    where = three_js_origin()
    try:
        packed = resources.files("trimesh").joinpath(_ARCHIVE).read_bytes()
        with zipfile.ZipFile(io.BytesIO(packed)) as z:
            page = z.read(_MEMBER).decode("utf-8")
    except (OSError, KeyError, ValueError, zipfile.BadZipFile) as exc:
        raise ThreeJsUnavailable(
            f"{where} has no three.js bundle ({_ARCHIVE}/{_MEMBER}: {exc})"
        ) from None
    start = page.find("<script>")
    end = page.find(_CONTROLS_END, start)
    if start < 0 or end < 0:
        raise ThreeJsUnavailable(
            f"the three.js bundle of {where} is not laid out as expected (no "
            "TrackballControls after three.js in its viewer template)"
        )
    lib = page[start + len("<script>") : end + len(_CONTROLS_END)]
    if "WebGLRenderer" not in lib or "@license" not in lib[:200] or "</script" in lib:
        raise ThreeJsUnavailable(f"the three.js bundle of {where} is not the library expected")
    return lib
