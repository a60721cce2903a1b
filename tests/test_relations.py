import numpy as np
import pytest

from estimator.relations import RelationConfig, relation_list, relation_masks, relations_and_support, supported_mask
from helpers import TABLE_TOP, table_scene
from physics.errors import SceneError
from physics.world import World


def box(lo, hi):
    return np.array([lo, hi], dtype=float)


def test_stack_and_container_on_hand_made_boxes():
    aabbs = np.stack([
        box([-0.75, -0.5, 0.57], [0.75, 0.5, 0.626]),   # 0 table
        box([0.0, 0.0, 0.628], [0.1, 0.1, 0.728]),      # 1 block on table (2 mm gap)
        box([0.02, 0.02, 0.73], [0.08, 0.08, 0.79]),    # 2 block on block 1
        box([0.3, 0.0, 0.626], [0.6, 0.2, 0.746]),      # 3 open box on table
        box([0.4, 0.05, 0.636], [0.46, 0.11, 0.696]),   # 4 ball in box 3
        box([2.0, 2.0, 0.0], [2.1, 2.1, 0.1]),          # 5 on the floor
    ])
    static = np.array([True, False, False, False, False, False])
    on, inside = relation_masks(aabbs, static=static)
    names = ["table", "b1", "b2", "box", "ball", "crate", "floor"]
    got_on = {(names[a], names[b]) for a, b in zip(*np.nonzero(on))}
    got_in = {(names[a], names[b]) for a, b in zip(*np.nonzero(inside))}
    assert got_on == {("b1", "table"), ("b2", "b1"), ("box", "table"), ("crate", "floor")}
    assert got_in == {("ball", "box")}  # not also "on the table" through the box's floor
    rel = relation_list(on, inside, names[:-1])
    assert {"subject": "ball", "predicate": "isIn", "object": "box", "p": 1.0} in rel


def test_margins_are_symmetric_and_hysteresis_holds():
    cfg = RelationConfig(margin=0.01, hysteresis=0.01)
    container = box([0, 0, 0], [0.3, 0.3, 0.1])
    for dx in (-0.015, 0.015):  # the same overhang on either side gives the same answer
        lo = np.array([0.0, 0.1, 0.01]) if dx < 0 else np.array([0.24, 0.1, 0.01])
        item = box(lo + [dx, 0, 0], lo + [0.06 + dx, 0.06, 0.07])
        on, inside = relation_masks(np.stack([container, item]), config=cfg, floor=False)
        assert not inside[1, 0]
        _, kept = relation_masks(np.stack([container, item]), config=cfg, floor=False,
                                 previous=(np.zeros((2, 3), bool), np.array([[False, False], [True, False]])))
        assert kept[1, 0]  # within margin + hysteresis: an existing fact is kept
    # batched over particles: (K, M, 2, 3)
    k = np.stack([np.stack([container, box([0.1, 0.1, 0.01], [0.2, 0.2, 0.05])])] * 3)
    on, inside = relation_masks(k, floor=False)
    assert inside.shape == (3, 2, 2) and inside[:, 1, 0].all() and on.shape == (3, 2, 3)
    with pytest.raises(ValueError):
        relation_masks(np.zeros((3, 3)))


def test_relations_on_pybullet_data_tray_and_mug():
    scene = table_scene(
        {"id": "tray", "urdf": "pybullet_data://tray/traybox.urdf", "mass": 1.0,
         "pose": {"position": [0, 0, TABLE_TOP + 0.012]}},
        {"id": "mug", "urdf": "pybullet_data://objects/mug.urdf", "mass": 0.3,
         "pose": {"position": [0.12, 0.1, TABLE_TOP + 0.05]}},
        {"id": "ball", "sphere": {"radius": 0.012}, "mass": 0.01,
         "pose": {"position": [0.12, 0.1, TABLE_TOP + 0.09]}},
        {"id": "b1", "box": {"size": [0.05, 0.05, 0.05]}, "pose": {"position": [0.5, 0.3, 0.66]}},
        {"id": "b2", "box": {"size": [0.04, 0.04, 0.04]}, "pose": {"position": [0.5, 0.3, 0.72]}})
    with World(scene) as w:
        w.step(480)
        on, inside = relation_masks(w.aabbs(), static=w.static)
    names = list(scene.object_ids) + ["floor"]
    got_on = {(names[a], names[b]) for a, b in zip(*np.nonzero(on))}
    got_in = {(names[a], names[b]) for a, b in zip(*np.nonzero(inside))}
    assert ("ball", "mug") in got_in and ("mug", "tray") in got_in and ("ball", "tray") in got_in
    assert ("tray", "table") in got_on and ("b1", "table") in got_on and ("b2", "b1") in got_on
    assert ("mug", "table") not in got_on and ("ball", "table") not in got_on


def test_supported_mask_is_a_looser_on_top():
    aabbs = np.stack([
        box([-0.75, -0.5, 0.57], [0.75, 0.5, 0.626]),  # table (static)
        box([0.0, 0.0, 0.65], [0.1, 0.1, 0.75]),       # 2.4 cm above the table: supported within 3 cm
        box([0.3, 0.0, 0.70], [0.4, 0.1, 0.80]),       # 7.4 cm above: not
        box([2.0, 2.0, 0.02], [2.1, 2.1, 0.12]),       # 2 cm above the floor
    ])
    static = np.array([True, False, False, False])
    on, inside = relation_masks(aabbs, static=static)
    assert not on[1].any()  # too high for the strict test
    sup = supported_mask(aabbs, inside, static=static, z_gap=0.03)
    assert sup.tolist() == [False, True, False, True]
    assert supported_mask(aabbs, inside, static=static, floor=False, z_gap=0.03).tolist() == [False, True, False, False]


def _reference(aabbs, cfg, floor=True, z_gap=0.03):
    """The definitions of the module docstring, pair by pair in plain Python (no hysteresis)."""
    m = len(aabbs)
    is_in = np.zeros((m, m), bool)
    on = np.zeros((m, m + 1), bool)
    sup = np.zeros(m, bool)
    for a in range(m):
        alo, ahi = aabbs[a]
        for b in range(m):
            if a == b:
                continue
            blo, bhi = aabbs[b]
            rim = max(cfg.rim, cfg.rim_fraction * (bhi[2] - blo[2]))
            is_in[a, b] = (all(alo[d] >= blo[d] - cfg.margin and ahi[d] <= bhi[d] + cfg.margin for d in (0, 1))
                           and blo[2] - cfg.margin <= alo[2] <= bhi[2] - rim
                           and all(ahi[d] - alo[d] <= bhi[d] - blo[d] + 1e-9 for d in (0, 1)))
            ov = min(min(ahi[d], bhi[d]) - max(alo[d], blo[d]) for d in (0, 1))
            on[a, b] = ov >= cfg.overlap and abs(alo[2] - bhi[2]) <= cfg.z_margin and not is_in[a, b]
            sup[a] |= ov >= cfg.overlap and abs(alo[2] - bhi[2]) <= z_gap
        on[a, m] = floor and abs(alo[2]) <= cfg.z_margin
        sup[a] |= (floor and abs(alo[2]) <= z_gap) or is_in[a].any()
    through = on.copy()
    for a in range(m):
        for b in range(m + 1):
            through[a, b] = on[a, b] and not any(is_in[a, c] and on[c, b] for c in range(m))
    return through, is_in, sup


def test_one_pass_relations_and_support_match_the_definitions_pair_by_pair():
    rng = np.random.default_rng(7)
    cfg = RelationConfig()
    k, m = 40, 6
    # a table, an open box on it, and objects dropped around: inside, on top, on the floor, in the air
    aabbs = np.zeros((k, m, 2, 3))
    aabbs[:, 0] = box([-0.75, -0.5, 0.57], [0.75, 0.5, 0.626])
    aabbs[:, 1] = box([0.0, 0.0, 0.626], [0.3, 0.2, 0.746])
    for j in range(2, m):
        size = rng.uniform(0.03, 0.08, (k, 3))
        lo = np.stack([rng.uniform(-0.05, 0.3, k), rng.uniform(-0.05, 0.2, k),
                       rng.choice([0.0, 0.636, 0.626, 0.746, 0.9], k) + rng.normal(0, 0.01, k)], axis=1)
        aabbs[:, j, 0], aabbs[:, j, 1] = lo, lo + size
    on, inside, sup = relations_and_support(aabbs, config=cfg, z_gap=0.03)
    on2, inside2 = relation_masks(aabbs, config=cfg)
    assert np.array_equal(on, on2) and np.array_equal(inside, inside2)
    assert np.array_equal(sup, supported_mask(aabbs, inside, config=cfg, z_gap=0.03))
    n_in = 0
    for p in range(k):
        ref_on, ref_in, ref_sup = _reference(aabbs[p], cfg)
        assert np.array_equal(on[p], ref_on) and np.array_equal(inside[p], ref_in), p
        assert np.array_equal(sup[p], ref_sup), p
        n_in += ref_in.sum()
    assert n_in > 5 and on[:, 2:, :].sum() > 20  # the draw did exercise both relations


def test_a_block_perceived_sunk_into_a_solid_block_is_not_in_it():
    lower = box([0.0, 0.0, 0.626], [0.1, 0.1, 0.726])
    upper = box([0.02, 0.02, 0.69], [0.08, 0.08, 0.75])  # sunk 3.6 cm into the lower block
    tray = box([0.3, 0.0, 0.626], [0.5, 0.2, 0.7])
    ball = box([0.35, 0.05, 0.636], [0.4, 0.1, 0.686])
    aabbs = np.stack([lower, upper, tray, ball])
    _, inside = relation_masks(aabbs, floor=False)
    assert inside[1, 0] and inside[3, 2]  # by the boxes alone, both look contained
    on, inside = relation_masks(aabbs, floor=False, hollow=np.array([False, False, True, False]))
    assert not inside[1, 0] and inside[3, 2]  # a solid block contains nothing; the tray still does
    _, inside2, _ = relations_and_support(aabbs, floor=False, hollow=np.array([False, False, True, False]))
    assert np.array_equal(inside, inside2)
    scene = table_scene({"id": "block", "box": {"size": [0.1, 0.1, 0.1]}, "pose": {"position": [0, 0, 0.7]}},
                        {"id": "bin", "container": {"size": [0.2, 0.2, 0.1], "wall": 0.01},
                         "pose": {"position": [0.4, 0, 0.7]}},
                        {"id": "ball", "sphere": {"radius": 0.02}, "pose": {"position": [0.4, 0, 0.8]}})
    assert scene.hollow == (False, False, True, False)  # the open container; not the (static) table
    from physics.scene import scene_from_dict, scene_to_dict
    data = scene_to_dict(scene)
    data["objects"][1]["hollow"] = True  # a scene file can say otherwise
    assert scene_from_dict(data).hollow == (False, True, True, False)
    assert scene_from_dict(scene_to_dict(scene_from_dict(data))).hollow == (False, True, True, False)
    data["objects"][1]["hollow"] = "yes"
    with pytest.raises(SceneError, match=r"objects\[1\]\.hollow"):
        scene_from_dict(data)
