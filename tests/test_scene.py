import json

import pytest

from physics.errors import SceneError
from physics.scene import load_scene, scene_from_dict, scene_to_dict

GOOD = """\
name: cup_behind_box
camera:
  position: [1.2, 0.0, 1.3]
  target: [0.0, 0.0, 0.7]
objects:
  - id: table
    static: true
    urdf: pybullet_data://table/table.urdf
    pose: {position: [0, 0, 0], orientation: [0, 0, 0, 1]}
  - id: blue_box
    container: {size: [0.30, 0.20, 0.12], wall: 0.01}
    mass: 0.7
  - id: cup
    cylinder: {radius: 0.04, height: 0.10}
    mass: 0.2
    friction: 0.6
    pose: {position: [0, 0.3, 0.7], orientation: [0, 0, 0, 2]}
"""


def test_load_good_scene(tmp_path):
    p = tmp_path / "s.yaml"
    p.write_text(GOOD)
    s = load_scene(p)
    assert s.object_ids == ("table", "blue_box", "cup")
    assert s.get("table").static and s.get("table").urdf.endswith("table/table.urdf")
    assert s.get("blue_box").shape == "container" and s.get("blue_box").wall == 0.01
    assert s.get("blue_box").position is None  # unknown until perceived
    assert s.get("cup").orientation == (0, 0, 0, 1.0)  # normalised
    assert s.camera.fov_deg == 60.0
    again = scene_from_dict(json.loads(json.dumps(scene_to_dict(s))))
    assert again.objects == s.objects and again.camera == s.camera


@pytest.mark.parametrize("bad, line, field, words", [
    ("    mass: 0.7\n", 12, "objects[1].mass", "must be > 0"),
    ("    mass: .nan\n", 12, "objects[1].mass", "finite"),
    ("    masss: 0.7\n", 12, "objects[1].masss", "unknown field"),
])
def test_bad_fields_are_located(tmp_path, bad, line, field, words):
    text = GOOD.replace("    mass: 0.7\n", bad.replace("0.7", "-1") if "must be" in words else bad)
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(SceneError) as e:
        load_scene(p)
    assert e.value.path == str(p) and e.value.line == line and e.value.field == field
    assert words in str(e.value) and f"{p}:{line}: {field}" in str(e.value)


def test_zero_quaternion_and_missing_urdf(tmp_path):
    p = tmp_path / "q.yaml"
    p.write_text(GOOD.replace("[0, 0, 0, 2]", "[0, 0, 0, 0]"))
    with pytest.raises(SceneError, match="zero-length quaternion") as e:
        load_scene(p)
    assert e.value.line == 17 and e.value.field == "objects[2].pose.orientation"
    p.write_text(GOOD.replace("pybullet_data://table/table.urdf", "meshes/nothere.urdf"))
    with pytest.raises(SceneError, match="URDF file not found") as e:
        load_scene(p)
    assert e.value.line == 8 and e.value.field == "objects[0].urdf"


def test_relative_urdf_and_other_errors(tmp_path):
    urdf = tmp_path / "m" / "thing.urdf"
    urdf.parent.mkdir()
    urdf.write_text("<robot name='x'><link name='l'/></robot>")
    s = scene_from_dict({"objects": [{"id": "a", "urdf": "m/thing.urdf"}]}, path=str(tmp_path / "s.yaml"))
    assert s.objects[0].urdf == str(urdf)
    with pytest.raises(SceneError, match="scene file not found"):
        load_scene(tmp_path / "missing.yaml")
    (tmp_path / "broken.yaml").write_text("objects: [\n  {id: a\n")
    with pytest.raises(SceneError, match="invalid YAML"):
        load_scene(tmp_path / "broken.yaml")
    for data, words in [({"objects": []}, "non-empty"),
                        ({"objects": [{"id": "a", "box": {"size": [1, 1, 1]}}, {"id": "a", "sphere": {"radius": 1}}]}, "duplicate"),
                        ({"objects": [{"id": "a", "box": {"size": [1, 1]}}]}, "list of 3"),
                        ({"objects": [{"id": "a"}]}, "exactly one geometry"),
                        ({"objects": [{"id": "a", "static": True, "sphere": {"radius": 1}}]}, "needs a pose"),
                        ({"objects": [{"id": "a", "container": {"size": [0.1, 0.1, 0.1], "wall": 0.06}}]}, "too thick")]:
        with pytest.raises(SceneError, match=words):
            scene_from_dict(data)


# -- property-based: any scene data gives a scene or a SceneError -----------------------------------------

from hypothesis import given  # noqa: E402
from hypothesis import strategies as st

from helpers import fuzz_settings, json_values  # noqa: E402

_OBJECT = st.fixed_dictionaries({"id": json_values()}, optional={
    k: json_values() for k in ("box", "sphere", "cylinder", "container", "mass", "pose", "static", "hollow",
                               "friction", "urdf")})


@fuzz_settings(300)
@given(st.one_of(json_values(), st.fixed_dictionaries({}, optional={
    "objects": st.one_of(st.lists(_OBJECT, max_size=3), json_values()), "camera": json_values(),
    "floor": json_values(), "name": json_values(), "version": json_values()})))
def test_any_scene_data_gives_a_scene_or_a_scene_error(data):
    try:
        scene = scene_from_dict(data)
    except SceneError as exc:
        assert str(exc)
        return
    assert all(isinstance(o.id, str) for o in scene.objects)


def test_workspace_given_or_derived_from_the_scene():
    base = {"objects": [{"id": "cup", "cylinder": {"radius": 0.03, "height": 0.08}, "pose": {"position": [1, 2, 0.7]}}]}
    lo, hi = scene_from_dict(base).workspace_bounds()
    assert lo.tolist() == [-2.0, -1.0, -0.5] and hi.tolist() == [4.0, 5.0, 3.7]
    given = scene_from_dict({**base, "workspace": {"min": [-1, -1, 0], "max": [1, 1, 2]}})
    assert [b.tolist() for b in given.workspace_bounds()] == [[-1, -1, 0], [1, 1, 2]]
    assert scene_from_dict(scene_to_dict(given)).workspace == given.workspace
    with pytest.raises(SceneError, match="workspace.max"):
        scene_from_dict({**base, "workspace": {"min": [0, 0, 0], "max": [1, -1, 1]}})
    with pytest.raises(SceneError, match="workspace: missing field 'max'"):
        scene_from_dict({**base, "workspace": {"min": [0, 0, 0]}})
