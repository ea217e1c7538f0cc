import copy

import pytest
import yaml
from conftest import REPO

from ocpipe.config import validate as C


def test_default_and_thesis_profiles_validate():
    base = C.load(REPO / "config" / "config.yaml")
    full = C.load(REPO / "config" / "config.yaml", REPO / "config" / "thesis.yaml")
    assert full["demos"]["num_demos"] == 1000 and 224 in full["frames"]["resolutions"]
    assert full["cameras"] == base["cameras"]  # untouched sections survive the merge


@pytest.mark.parametrize(
    "path, value, words",
    [
        (("frames", "resolutions"), [128, -1], ["frames.resolutions.1", "-1", ">= 32"]),
        (("sim", "control_mode"), "pd_ee_delta_pose", ["sim.control_mode", "pd_joint_pos"]),
        (("tasks",), ["PushCube-v1"], ["tasks.0", "PickCube-v1", "StackCube-v1"]),
        (("demos", "num_demos"), "many", ["demos.num_demos", "'many'", "integer"]),
        (("cameras", "base", "eye"), [0.3, 0.0], ["cameras.base.eye", "too short"]),
        (("frames", "camera_sets", "PickCube-v1"), ["native"], ["frames.camera_sets.PickCube-v1.0", "dual"]),
    ],
)
def test_bad_values_name_the_key_and_what_is_allowed(default_config, path, value, words):
    cfg = copy.deepcopy(default_config)
    node = cfg
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    with pytest.raises(C.ConfigError) as exc:
        C.validate(cfg)
    for word in words:
        assert word in str(exc.value)


def test_unknown_key_is_rejected(default_config):
    cfg = copy.deepcopy(default_config)
    cfg["demos"]["num_demo"] = 5
    with pytest.raises(C.ConfigError, match="num_demo"):
        C.validate(cfg)


def test_demo_seeds_may_not_reach_the_held_out_pool(default_config):
    cfg = copy.deepcopy(default_config)
    cfg["demos"]["seed_start"] = 9900  # 100 demos x 2 attempts -> 9900..10099
    with pytest.raises(C.ConfigError, match=r"demos.seed_start.*9900..10099.*10000..10999"):
        C.validate(cfg)
    cfg["demos"]["seed_start"] = 11000  # above the pool is fine
    C.validate(cfg)


def test_import_source_needs_paths(default_config):
    cfg = copy.deepcopy(default_config)
    cfg["demos"]["source"] = "import"
    with pytest.raises(C.ConfigError, match="demos.import.PickCube-v1.h5"):
        C.validate(cfg)


def test_missing_file_is_named(tmp_path):
    with pytest.raises(C.ConfigError, match="nope.yaml"):
        C.load(tmp_path / "nope.yaml")


def test_deep_merge_keeps_siblings():
    merged = C.deep_merge({"a": {"b": 1, "c": 2}, "d": 3}, {"a": {"b": 5}})
    assert merged == {"a": {"b": 5, "c": 2}, "d": 3}


def test_schema_file_is_yaml_with_every_top_level_key(default_config):
    schema = yaml.safe_load(C.SCHEMA_PATH.read_text())
    assert set(schema["properties"]) == set(default_config)


def test_each_encoder_depends_on_the_weights_it_loads_and_says_which_are_missing(default_config):
    from ocpipe.config.experiments import encoder_checkpoint, missing_weights

    cfg = {**default_config, "encoders": {**default_config["encoders"],
                                          "spot": {**default_config["encoders"]["spot"], "checkpoint": None,
                                                   "dino_checkpoint": None},
                                          "dino": {**default_config["encoders"]["dino"], "checkpoint": None}}}
    assert encoder_checkpoint(cfg, "slots_ssl").endswith("model.pt") and encoder_checkpoint(cfg, "state") == []
    assert missing_weights(cfg, {"encoder": "spot"}).startswith("needs weights: set encoders.spot.checkpoint")
    assert missing_weights(cfg, {"encoder": "dino_grid4"}) == (
        "needs weights: set encoders.dino.checkpoint (dino_vitbase16_pretrain.pth)")
    assert missing_weights(cfg, {"encoder": "slots_ssl"}) is None
    cfg["encoders"]["spot"]["dino_checkpoint"] = "dino.pth"  # SPOT's slots are trained on the given DINO
    assert missing_weights(cfg, {"encoder": "spot"}) is None
    assert encoder_checkpoint(cfg, "spot").endswith("slot_module.pt")
    cfg["encoders"]["spot"]["checkpoint"] = "spot.pt.tar"  # the official SPOT checkpoint wins
    assert encoder_checkpoint(cfg, "spot") == "spot.pt.tar"
    cfg["encoders"]["dino"]["checkpoint"] = "dino.pth"
    assert encoder_checkpoint(cfg, "dino_dense") == "dino.pth" and missing_weights(cfg, {"encoder": "dino_cls"}) is None


def test_check_config_refuses_a_table_the_study_does_not_define(tmp_path, capsys):
    from ocpipe import cli

    extra = tmp_path / "extra.yaml"
    extra.write_text("tables:\n  table_dropout: {none: pure_visual}\n")
    assert cli.main(["check-config", str(REPO / "config" / "config.yaml"), str(extra)]) == 1
    assert "tables.table_dropout: not a table of the study" in capsys.readouterr().err
