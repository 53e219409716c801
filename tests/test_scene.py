"""The scene file: defaults, camera modes, overrides, views, every error with its line, and the key locator."""

from __future__ import annotations

import json
import math
import os
import re
import tomllib
from pathlib import Path

import pytest
from isplat.scene_schema import STOP_EARLY_TERMINATION, RenderOptions, defaults
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from isplat.errors import IsplatError
from isplat.scene import (CAMERA_KEYS, CUT_KEYS, DATA_KEYS, IMAGE_KEYS, LIGHT_KEYS, RENDER_KEYS, SHADING_KEYS,
                          TOP_KEYS, TRANSFER_KEYS, VIEWS_KEYS, VOLUME_KEYS, Camera, Image, RenderOptions, Scene,
                          Shading, Transfer, Volume, load_scene, locate_keys, parse_scene, scene_to_dict)

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "formats" / "examples" / "scene"
VALID = sorted((EXAMPLES / "valid").glob("*.toml"))
INVALID = sorted((EXAMPLES / "invalid").glob("*.toml"))

BASE = """\
[data]
augmented = "a.h5"
index = "i.h5"

[transfer]
opacity = [[0, 0.0], [255, 1.0]]
"""


def parse(text: str, overrides=(), name="s.toml") -> Scene:
    return parse_scene(text, Path("/scenes"), name, overrides)


def error(text: str, overrides=(), name="s.toml") -> str:
    with pytest.raises(IsplatError) as info:
        parse(text, overrides, name)
    message = str(info.value)
    assert "\n" not in message
    return message


# ------------------------------------------------------------------------------------------------ format examples

def test_examples_exist():
    assert len(VALID) >= 6 and len(INVALID) >= 30


@pytest.mark.parametrize("path", VALID, ids=lambda p: p.name)
def test_valid_example_decodes_as_expected(path):
    scene = load_scene(path)
    got = scene_to_dict(scene, path.parent)
    got["path"] = path.name
    expected = json.loads(path.with_suffix(".expected.json").read_text())
    # the expected files (formats/, kept by the formats' owner) predate scene version 6: its render keys take
    # their defaults there (version 7's render.termination, whose default depends on the version, is in them)
    for key in ("mode", "window", "intensity_color", "slice_stride"):
        expected["render"].setdefault(key, defaults(RenderOptions)[key])
    assert got == expected
    assert scene.path == path.resolve()
    assert scene.views and all(isinstance(v, Camera) for v in scene.views)


@pytest.mark.parametrize("path", INVALID, ids=lambda p: p.name)
def test_invalid_example_fails_with_expected_message(path):
    text = path.read_text()
    first = text.splitlines()[0]
    assert first.startswith("# expect: ")
    expected = first[len("# expect: "):]
    with pytest.raises(IsplatError) as info:
        parse_scene(text, path.parent, path.name)
    assert str(info.value) == expected


@pytest.mark.parametrize("name", ["head.toml", "engine.toml"])
def test_shipped_examples_load(name):
    scene = load_scene(ROOT / "examples" / name)
    assert scene.data.augmented == ROOT / "examples" / name.replace(".toml", ".aug.h5")
    assert scene.data.index == ROOT / "examples" / name.replace(".toml", ".idx.h5")


def test_spec_documents_every_key():
    spec = (ROOT / "formats" / "scene.md").read_text()
    for keys in (TOP_KEYS, DATA_KEYS, IMAGE_KEYS, VOLUME_KEYS, CAMERA_KEYS, TRANSFER_KEYS, SHADING_KEYS, LIGHT_KEYS,
                 CUT_KEYS, RENDER_KEYS, VIEWS_KEYS):
        for key in keys:
            assert re.search(rf"`{key}`|\[{key}\]|\.{key}\]", spec), key


# ------------------------------------------------------------------------------------------------ defaults and modes

def test_defaults():
    s = parse(BASE)
    assert s.path is None
    assert s.data.augmented == Path("/scenes/a.h5") and s.data.index == Path("/scenes/i.h5")
    assert (s.image.width, s.image.height, s.image.background, s.image.bit_depth) == (256, 256, (0, 0, 0, 1), 8)
    assert s.volume.spacing is None and s.volume.origin is None
    assert s.volume.axes is None                      # the file's axes_lps, else the identity (version 5)
    assert parse("version = 4\n" + BASE).volume.axes == ((1, 0, 0), (0, 1, 0), (0, 0, 1))
    assert parse("version = 4\n" + BASE).camera.view == "none" and s.camera.view == "auto"
    assert parse(BASE, ["camera.up=[0, 1, 0]"]).camera.view == "none"       # a scene with its own up
    c = s.camera
    assert (c.projection, c.mode, c.azimuth, c.elevation, c.distance, c.roll, c.target) == \
        ("orthographic", "orbit", 0.0, 0.0, None, 0.0, None)
    assert (c.up, c.zoom, c.fov, c.near) == ((0, 0, 1), 1.0, 30.0, 0.0)
    assert s.transfer.color == ((0, 1, 1, 1),) and s.transfer.gradient_opacity == () and s.transfer.unit_distance == 0
    sh = s.shading
    assert (sh.enabled, sh.ambient, sh.diffuse, sh.specular, sh.shininess, sh.two_sided) == \
        (True, 0.25, 0.75, 0.3, 24.0, True)
    assert len(sh.lights) == 1 and sh.lights[0].intensity == 1.0
    n = math.sqrt(0.4 ** 2 + 0.6 ** 2 + 1)
    assert sh.lights[0].direction == pytest.approx((-0.4 / n, 0.6 / n, 1 / n))
    assert s.cuts == ()
    r = s.render
    assert (r.method, r.early_termination, r.footprint_radius, r.footprint_sigma, r.footprint_table, r.precision,
            r.threads) == ("indexed", 0.986, 2.5, 0.7, 1024, "float32", 0)
    # a pixel that is stopped, and every frame of a file before version 8, stops at 0.99
    for text in ("version = 7\n" + BASE, BASE + '[render]\ntermination = "stop"\n',
                 BASE + '[render]\nclassification = "pre"\n', BASE + '[render]\nmode = "mip"\n'):
        assert parse(text).render.early_termination == 0.99
    assert parse("version = 7\n" + BASE).render.termination == "fill"
    assert parse(BASE + "[render]\nearly_termination = 0.9\n").render.early_termination == 0.9
    assert s.views == (s.camera,)


def test_defaults_are_the_dataclass_defaults():
    """Each default is written once, on the schema's dataclass: an absent key gives the field's default."""
    s = parse(BASE)
    assert (s.image, s.volume, s.camera, s.shading, s.render) == (Image(), Volume(), Camera(), Shading(),
                                                                  RenderOptions())
    assert s.transfer == Transfer(s.transfer.opacity) and s.fps == 12.0
    # (a stopped pixel's early termination, STOP_EARLY_TERMINATION, is the one default that depends on another key)
    assert parse("version = 3\n" + BASE).render == RenderOptions(classification="pre", termination="stop",
                                                                  early_termination=STOP_EARLY_TERMINATION)
    assert parse(BASE + '[render]\nsheets = "image"\n').render == RenderOptions(sheets="image", classification="pre",
                                                                                 termination="stop",
                                                                                 early_termination=0.99)


def test_types_are_python_floats_and_tuples():
    s = parse(BASE + "[camera]\nazimuth = 45\ntarget = [1, 2, 3]\n")
    assert type(s.camera.azimuth) is float and s.camera.target == (1.0, 2.0, 3.0)
    assert all(type(x) is float for x in s.camera.target)
    assert isinstance(s.transfer.opacity, tuple) and isinstance(s.transfer.opacity[0], tuple)
    hash(s)  # frozen and hashable all the way down


def test_shading_disabled_has_no_default_light():
    assert parse(BASE + "[shading]\nenabled = false\n").shading.lights == ()


def test_rgb_background_gets_alpha_one_and_rgba_is_kept():
    assert parse(BASE + "[image]\nbackground = [1, 0.5, 0]\n").image.background == (1, 0.5, 0, 1)
    assert parse(BASE + "[image]\nbackground = [1, 0.5, 0, 0]\n").image.background == (1, 0.5, 0, 0)


def test_axes_are_reorthonormalised():
    s = parse(BASE + "[volume]\naxes = [[0.7071, 0.7071, 0], [-0.7071, 0.7071, 0], [0, 0, 1]]\n")
    i, j, k = s.volume.axes
    for a in (i, j, k):
        assert sum(x * x for x in a) == pytest.approx(1, abs=1e-15)
    assert sum(x * y for x, y in zip(i, j)) == pytest.approx(0, abs=1e-15)


def test_look_at_mode():
    c = parse(BASE + "[camera]\nprojection = 'perspective'\nposition = [0, -9, 0]\nlook_at = [0, 0, 0]\n").camera
    assert (c.mode, c.position, c.look_at, c.projection) == ("look_at", (0, -9, 0), (0, 0, 0), "perspective")


def test_paper_mode_orthogonalises_view_up():
    c = parse(BASE + "[camera]\nreference_point = [1, 2, 3]\nview_plane_normal = [0, 0, 5]\n"
              "view_up = [0, 1, 1]\n").camera
    assert c.mode == "paper" and c.eye is None
    assert c.view_plane_normal == (0, 0, 1)
    assert c.view_up == pytest.approx((0, 1, 0))


def test_explicit_mode_and_roll_in_every_mode():
    c = parse(BASE + "[camera]\nmode = 'look_at'\nposition = [5, 0, 0]\nlook_at = [0, 0, 0]\nroll = 10\n").camera
    assert c.mode == "look_at" and c.roll == 10


def test_unit_vectors_are_normalised():
    s = parse(BASE + "[camera]\nup = [0, 0, 7]\n[[cut]]\nnormal = [3, 0, 4]\n")
    assert s.camera.up == (0, 0, 1) and s.cuts[0].normal == pytest.approx((0.6, 0, 0.8))


def test_full_method_needs_no_index():
    s = parse("[data]\naugmented = 'a.h5'\n[transfer]\nopacity = [[9, 1]]\n[render]\nmethod = 'full'\n")
    assert s.data.index is None and s.render.method == "full"


def test_absolute_and_dotdot_paths():
    s = parse("[data]\naugmented = '/x/a.h5'\nindex = '../i.h5'\n[transfer]\nopacity = [[9, 1]]\n")
    assert s.data.augmented == Path("/x/a.h5") and s.data.index == Path("/i.h5")


# ------------------------------------------------------------------------------------------------ views

def test_orbit_steps():
    s = parse(BASE + "[camera]\nazimuth = 10\nelevation = 20\n[views]\norbit_steps = 36\n")
    assert len(s.views) == 36
    assert [v.azimuth for v in s.views[:3]] == [10, 20, 30]
    assert all(v.elevation == 20 for v in s.views)
    assert s.views[0] == s.camera


def test_view_list_merges_over_camera():
    s = parse(BASE + "[camera]\nelevation = 20\nzoom = 2\n[views]\n"
              "list = [{azimuth = 90}, {elevation = -5, projection = 'perspective'}]\n")
    assert [(v.azimuth, v.elevation, v.zoom, v.projection) for v in s.views] == \
        [(90, 20, 2, "orthographic"), (0, -5, 2, "perspective")]
    assert s.camera.azimuth == 0


def test_view_list_may_switch_to_another_mode_when_camera_has_no_mode_keys():
    s = parse(BASE + "[views]\nlist = [{azimuth = 90}, {position = [0, -5, 0], look_at = [0, 0, 0]}]\n")
    assert [v.mode for v in s.views] == ["orbit", "look_at"]


# ------------------------------------------------------------------------------------------------ overrides

def test_overrides():
    s = parse(BASE, ["camera.azimuth=45", "render.method=full", "transfer.opacity=[[0,0],[128,1]]",
                     "shading.enabled=false", "image.width=512", "camera.projection = perspective"])
    assert s.camera.azimuth == 45 and s.render.method == "full"
    assert s.transfer.opacity == ((0, 0), (128, 1))
    assert s.shading.enabled is False and s.image.width == 512 and s.camera.projection == "perspective"


def test_later_override_wins_and_table_values_work():
    s = parse(BASE, ["camera.azimuth=1", "camera.azimuth=2", "views={orbit_steps = 4}"])
    assert s.camera.azimuth == 2 and len(s.views) == 4


def test_override_array_elements_and_append():
    text = BASE + "[[cut]]\nnormal = [1, 0, 0]\n"
    s = parse(text, ["cut[0].normal=[0,1,0]", "cut[1].point=[0,0,9]"])
    assert [c.normal for c in s.cuts] == [(0, 1, 0), (1, 0, 0)]
    assert s.cuts[1].point == (0, 0, 9)
    assert "has 1 elements; index 5" in error(text, ["cut[5].normal=[0,1,0]"])


def test_override_data_path_is_relative_to_working_folder():
    s = parse(BASE, ["data.augmented=other.h5"])
    assert s.data.augmented == Path(os.getcwd()) / "other.h5"
    assert s.data.index == Path("/scenes/i.h5")


def test_override_errors_name_the_set_argument():
    assert error(BASE, ["camera.fov=200"]) == \
        "--set camera.fov=200: camera.fov = 200: expected a number of degrees with 0 < fov < 180"
    assert error(BASE, ["image.widht=3"]).startswith("--set image.widht=3: unknown key 'image.widht'")
    assert error(BASE, ["camera.fvo=3"]).endswith("did you mean 'fov'?")
    assert error(BASE, ["camera.azimuth"]) == "--set camera.azimuth: expected key=value, e.g. camera.azimuth=45"
    assert error(BASE, ["=3"]) == "--set =3: empty key before '='"
    assert error(BASE, ["data.augmented.x=3"]) == "--set data.augmented.x=3: 'data.augmented' is not a table"
    assert "bad key" in error(BASE, ["camera..fov=3"])
    assert error(BASE, ["transfer.opacity=[[0, 2]]"]) == \
        "--set transfer.opacity=[[0, 2]]: transfer.opacity[0] = [0, 2]: opacity must be in [0, 1]"
    assert error(BASE, ["data.index="]) == '--set data.index=: data.index = "": expected a non-empty file path'


def test_override_mixing_modes_names_both():
    msg = error(BASE + "[camera]\nazimuth = 3\n", ["camera.position=[1,2,3]"])
    assert msg.startswith("--set camera.position=[1,2,3]: camera.position = [1, 2, 3]: cannot be combined with "
                          "camera.azimuth on line 8")


def test_missing_key_removed_table_via_override():
    assert error(BASE, ["data={index = 'x'}"]) == "--set data={index = 'x'}: missing required key 'data.augmented'"


# ------------------------------------------------------------------------------------------------ errors

def test_syntax_error_at_end_of_document():
    assert error('[data]\naugmented = "a.h5', name="x.toml").startswith("x.toml:2: TOML syntax error: ")


@pytest.mark.parametrize("value", ["inf", "-inf", "nan", "true", '"3"', "[1]", "1979-05-27"])
def test_numbers_refuse_non_finite_booleans_strings(value):
    msg = error(BASE + f"[camera]\nzoom = {value}\n")
    assert msg.startswith("s.toml:8: camera.zoom = ")
    assert "expected a number > 0" in msg


@pytest.mark.parametrize("value", ["[1, 2, inf]", "[1, true, 3]", "[1, 2]", "[1, 2, 3, 4]", '"up"'])
def test_vectors_refuse_bad_components(value):
    assert error(BASE + f"[camera]\ntarget = {value}\n").startswith("s.toml:8: camera.target = ")


@pytest.mark.parametrize("value", ["1.0", '"1"', "true", "0"])
def test_version_must_be_integer_one(value):
    assert error(f"version = {value}\n" + BASE).startswith(f"s.toml:1: version = ")


def test_version_is_checked_before_unknown_keys():
    from isplat.scene_schema import SCENE_VERSION

    v = SCENE_VERSION + 1
    assert f"version = {v}: this isplat reads scene versions 1 to {SCENE_VERSION}" in \
        error(f"version = {v}\n" + BASE + "[future]\nx = 1\n")


@pytest.mark.parametrize("key, table", [("units", "transfer"), ("preset", "transfer"), ("frames", "views"),
                                        ("path", "views"), ("fps", "views")])
def test_keys_of_version_2_are_refused_in_a_version_1_file(key, table):
    value = '"data"' if key == "units" else '"ct-bone"' if key == "preset" else "[]" if key == "path" else "10"
    text = BASE if table == "transfer" else BASE + "[views]\n"
    if table == "transfer":
        text = text.replace("[transfer]\n", f"[transfer]\n{key} = {value}\n")
    else:
        text += f"{key} = {value}\n"
    msg = error("version = 1\n" + text)
    assert f"{table}.{key} = " in msg and "new in scene version 2" in msg


def test_version_1_files_still_read():
    parse_scene("version = 1\n" + BASE, ".", "s.toml")
    parse_scene("version = 2\n" + BASE, ".", "s.toml")
    parse_scene("version = 3\n" + BASE, ".", "s.toml")
    parse_scene("version = 4\n" + BASE, ".", "s.toml")


def test_point_rows_type_errors():
    assert error(BASE.replace("[[0, 0.0], [255, 1.0]]", "[[0, true]]")) == \
        "s.toml:6: transfer.opacity[0] = [0, true]: expected [density, opacity]: 2 numbers (got a boolean)"
    assert error(BASE.replace("[[0, 0.0], [255, 1.0]]", "[[0, nan]]")) == \
        "s.toml:6: transfer.opacity[0] = [0, nan]: expected [density, opacity]: 2 finite numbers"
    assert error(BASE.replace("[[0, 0.0], [255, 1.0]]", '"ramp"')) == \
        's.toml:6: transfer.opacity = "ramp": expected an array of [density, opacity] points (got a string)'


def test_unknown_key_in_multiline_and_nested_positions():
    text = '''\
title = """
[camera]
fov = 1
"""
'''
    # a multi-line string that looks like a table: the locator must not be fooled
    assert error(text + BASE) == \
        "s.toml:1: unknown key 'title' (known top-level keys: camera, cut, data, image, labels, render, shading, " \
        "transfer, version, views, volume)"


def test_array_of_tables_element_lines():
    text = BASE + "[[cut]]\nnormal = [1, 0, 0]\n\n[[cut]]  # second\npoint = [0, 0, 0]\nnormal = [0, 0, 0]\n"
    assert error(text) == "s.toml:12: cut[1].normal = [0, 0, 0]: expected a plane normal (world): 3 numbers, " \
                          "not all zero"
    assert error(BASE + "[[cut]]\nnrmal = [1, 0, 0]\n").startswith("s.toml:8: unknown key 'cut[0].nrmal'")


def test_cut_must_be_array_of_tables():
    assert error(BASE + "[cut]\nnormal = [1, 0, 0]\n").startswith(
        "s.toml:7: cut = {normal = [1, 0, 0]}: expected an array of tables ([[cut]])")


def test_long_values_are_shortened():
    msg = error(BASE + "[camera]\nmode = \"" + "x" * 200 + "\"\n")
    assert "..." in msg and len(msg) < 200


def test_load_scene_file_errors(tmp_path):
    with pytest.raises(IsplatError, match="scene file does not exist"):
        load_scene(tmp_path / "nope.toml")
    with pytest.raises(IsplatError, match="is a folder"):
        load_scene(tmp_path)
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b"[data]\naugmented = '\xff'\n")
    with pytest.raises(IsplatError, match=r"bad.toml:2: the scene file is not UTF-8 text"):
        load_scene(bad)
    bom = tmp_path / "bom.toml"
    bom.write_bytes(b"\xef\xbb\xbf" + BASE.encode())
    assert load_scene(bom).data.augmented == tmp_path / "a.h5"


def test_load_scene_names_the_path_as_given(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    Path("s.toml").write_text(BASE + "[image]\nwidth = 0\n")
    with pytest.raises(IsplatError) as info:
        load_scene("s.toml")
    assert str(info.value) == "s.toml:8: image.width = 0: expected an integer number of pixels in 1..8192"


# ------------------------------------------------------------------------------------------------ locator

def test_locator_basic_shapes():
    text = '''\
a = 1
b.c = "x # not a comment"   # comment [z]
[t]
'quoted key' = { p = 1, q = [2, 3] }
"d.e" = """
x = 1
"""
arr = [
  1,   # one
  [2,
   3],
]
[[aot]]
k = 1
[aot.sub]
m = 2
[[aot]]
k = 3
'''
    loc = locate_keys(text)
    assert loc[("a",)] == 1 and loc[("b", "c")] == 2 and loc[("b",)] == 2
    assert loc[("t",)] == 3 and loc[("t", "quoted key")] == 4 and loc[("t", "quoted key", "q", 1)] == 4
    assert loc[("t", "d.e")] == 5 and ("t", "x") not in loc
    assert loc[("t", "arr", 0)] == 9 and loc[("t", "arr", 1)] == 10 and loc[("t", "arr", 1, 1)] == 11
    assert loc[("aot", 0)] == 13 and loc[("aot", 0, "k")] == 14 and loc[("aot", 0, "sub", "m")] == 16
    assert loc[("aot", 1, "k")] == 18


def test_locator_gives_up_quietly_on_nonsense():
    assert locate_keys("a = 1\n=== ???") == {("a",): 1}


_BARE = st.from_regex(r"[a-z][a-z0-9_-]{0,6}", fullmatch=True)
_QUOTED = st.sampled_from([('"a b"', "a b"), ('"x.y"', "x.y"), ("'lit [k]'", "lit [k]"), ('"#h"', "#h"),
                           ('"="', "=")])
_KEY = st.one_of(_BARE.map(lambda k: (k, k)), _QUOTED)
_VALUE = st.sampled_from([
    "1", "-2.5e3", "true", "inf", '"s # no comment"', "'x = [1]'", '"a \\" b"', "1979-05-27T07:32:00Z",
    '"""multi\n[line]\nk = 2"""', "'''lit\nline'''", "[1, 2]", "[\n  1, # c\n  [2,\n 3],\n]", "{ a = 1, b = \"}\" }",
    "[{ a = 1 }, { b = [1, 2] }]", "[]", "[ # c\n]",
])
_COMMENT = st.sampled_from(["", "  # trailing [x] = 1", "\t#"])


def _unique_keys(min_size=0, max_size=4):
    return st.lists(_KEY, min_size=min_size, max_size=max_size, unique_by=lambda k: k[1])


@st.composite
def _toml_documents(draw):
    """A random TOML document and the exact line of every key in it."""
    lines: list[str] = []
    expect: dict[tuple, int] = {}

    def emit(text):
        lines.append(text)
        return len(lines)  # the line where ``text`` starts

    def keyvals(prefix, keys):
        for src, dec in keys:
            if draw(st.booleans()):
                emit(draw(st.sampled_from(["", "# a comment", "   "])))
            value = draw(_VALUE)
            line = emit(f"{src} = {value}{draw(_COMMENT)}")
            for _ in range(value.count("\n")):
                lines.append(None)  # placeholder lines are joined below
            expect[prefix + (dec,)] = line

    tables = draw(_unique_keys(0, 5))
    top = draw(_unique_keys(0, 3).map(lambda ks: [k for k in ks if k[1] not in {t[1] for t in tables}]))
    keyvals((), top)
    styles = [draw(st.sampled_from(["header", "dotted", "inline", "aot"])) for _ in tables]
    # dotted and inline tables must come before the first header
    for (src, dec), style in zip(tables, styles):
        if style == "dotted":
            for ksrc, kdec in draw(_unique_keys(1, 3)):
                value = draw(_VALUE)
                expect[(dec, kdec)] = emit(f"{src} . {ksrc} = {value}")
                lines.extend([None] * value.count("\n"))
        elif style == "inline":
            keys = draw(_unique_keys(0, 3))
            line = emit(f"{src} = {{ " + ", ".join(f"{k} = 1" for k, _ in keys) + " }")
            expect[(dec,)] = line
            for _, kdec in keys:
                expect[(dec, kdec)] = line
    for (src, dec), style in zip(tables, styles):
        if style == "header":
            expect[(dec,)] = emit(f"[ {src} ]{draw(_COMMENT)}")
            keys = draw(_unique_keys())
            keyvals((dec,), keys)
            subs = [k for k in draw(_unique_keys(0, 2)) if k[1] not in {d for _, d in keys}]
            for ssrc, sdec in subs:
                expect[(dec, sdec)] = emit(f"[{src}.{ssrc}]")
                keyvals((dec, sdec), draw(_unique_keys()))
        elif style == "aot":
            for n in range(draw(st.integers(1, 3))):
                expect[(dec, n)] = emit(f"[[{src}]]")
                keyvals((dec, n), draw(_unique_keys()))
    # a value spanning several lines was emitted as one list item followed by placeholders
    text = "\n".join(x for x in lines if x is not None) + "\n"
    return text, expect


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_toml_documents())
def test_locator_finds_the_line_of_every_key(doc):
    text, expect = doc
    tree = tomllib.loads(text)  # the generator writes valid TOML
    loc = locate_keys(text)
    source_lines = text.split("\n")
    for path, line in expect.items():
        node = tree
        for part in path:
            node = node[part]
        assert loc.get(path) == line, (path, text)
        if isinstance(path[-1], str):
            assert re.search(re.escape(path[-1]), source_lines[line - 1]) or '"' in source_lines[line - 1]


@settings(max_examples=60, deadline=None)
@given(st.sampled_from(["width", "height", "bit_depth"]), st.integers(0, 6), st.integers(-5, 0))
def test_error_line_points_at_the_bad_key(key, blank_lines, value):
    text = BASE + "\n" * blank_lines + f"[image]\n# c\n{key} = {value}\n"
    msg = error(text)
    line = int(msg.split(":")[1])
    assert text.splitlines()[line - 1].startswith(f"{key} = ")


def test_scene_examples_window_file_is_the_augmented_example():
    copy = EXAMPLES / "valid" / "window-0-100.aug.h5"
    assert copy.read_bytes() == (ROOT / "formats" / "examples" / "augmented" / "valid.aug.h5").read_bytes()


def test_a_scene_without_version_gets_the_current_defaults():
    from isplat.scene_schema import DEFAULTS_BEFORE, IDENTITY_AXES

    assert set(DEFAULTS_BEFORE) == {("render", "classification"), ("camera", "view"), ("volume", "axes"),
                                    ("render", "termination"), ("render", "early_termination")}
    s = parse_scene(BASE, ".", "s.toml")
    assert (s.render.classification, s.camera.view, s.volume.axes, s.render.termination) == ("post", "auto", None,
                                                                                               "fill")
    s1 = parse_scene("version = 1\n" + BASE, ".", "s.toml")
    assert (s1.render.classification, s1.camera.view, s1.volume.axes, s1.render.termination) == (
        "pre", "none", IDENTITY_AXES, "stop")
    s4 = parse_scene("version = 4\n" + BASE, ".", "s.toml")
    assert (s4.render.classification, s4.camera.view, s4.volume.axes, s4.render.termination) == (
        "post", "none", IDENTITY_AXES, "stop")
    s6 = parse_scene("version = 6\n" + BASE, ".", "s.toml")
    assert (s6.render.classification, s6.camera.view, s6.render.termination) == ("post", "auto", "stop")
    s7 = parse_scene("version = 7\n" + BASE, ".", "s.toml")
    assert (s7.render.termination, s7.render.early_termination, s.render.early_termination) == ("fill", 0.99, 0.986)
    # "fill" takes the colour of a post-classified composite sample: the other frames stop in every version
    for extra in ('classification = "pre"', 'mode = "mip"', 'sheets = "image"'):
        assert parse_scene(BASE + f"[render]\n{extra}\n", ".", "s.toml").render.termination == "stop"


@pytest.mark.parametrize("text, kept", [
    ("", None),
    ("version = 5\n", ['render.termination = "stop"']),
    ("version = 6\n", ['render.termination = "stop"']),
    ("version = 6\n[render]\nclassification = \"pre\"\n", None),
    ("version = 6\n[render]\nmode = \"mip\"\n", None),
    ("version = 1\n", ['render.classification = "pre" (the paper\'s splatting)', 'camera.view = "none"',
                       "volume.axes = identity"]),
    ("version = 3\n[render]\nclassification = \"post\"\n", ['camera.view = "none"', "volume.axes = identity",
                                                             'render.termination = "stop"']),
    ("version = 3\n[render]\nsheets = \"image\"\n", ['camera.view = "none"', "volume.axes = identity"]),
    ("version = 4\n", ['camera.view = "none"', "volume.axes = identity", 'render.termination = "stop"']),
    ("version = 4\n[camera]\nup = [0, 0, 1]\n[volume]\naxes = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n",
     ['render.termination = "stop"']),
    ("version = 4\n[camera]\nup = [0, 0, 1]\n[volume]\naxes = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n[render]\n"
     "termination = \"stop\"\n", None),
    ("version = 7\n", ["render.early_termination = 0.99 (also where a pixel that reaches it is filled)"]),
    ("version = 7\n[render]\ntermination = \"stop\"\n", None),
    ("version = 7\n[render]\nclassification = \"pre\"\n", None),
    ("version = 7\n[render]\nearly_termination = 0.99\n", None),
])
def test_old_defaults_note_names_what_an_old_version_keeps(text, kept):
    from isplat.scene import old_defaults_note, scene_tree

    note = old_defaults_note(scene_tree(text, "s.toml", [])[0], "s.toml")
    if kept is None:
        assert note is None
        return
    v = text.split("\n")[0].split("= ")[1]
    assert note.startswith(f"s.toml: version = {v} keeps version-{v} defaults: ") and "\n" not in note
    from isplat.scene_schema import SCENE_VERSION

    assert note.endswith(f"say version = {SCENE_VERSION} for the current defaults")
    for k in kept:
        assert k in note
    assert ("render.classification" in note) == any(k.startswith("render.classification") for k in kept)
    assert ("render.termination" in note) == any(k.startswith("render.termination") for k in kept)
