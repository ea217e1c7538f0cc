"""config/README.md is generated from the schema's descriptions and config/config.yaml, and must stay in sync."""

import yaml
from conftest import REPO

from ocpipe import cli
from ocpipe.config import docs as config_docs

SCHEMA = REPO / "workflow" / "schemas" / "config.schema.yaml"


def _inputs():
    return config_docs.load_inputs(SCHEMA, REPO / "config" / "config.yaml")


def _resolve(schema: dict, node: dict) -> dict:
    while isinstance(node, dict) and "$ref" in node:
        target = schema
        for part in node["$ref"].lstrip("#/").split("/"):
            target = target[part]
        node = {**target, **{k: v for k, v in node.items() if k != "$ref"}}
    return node


def _undocumented(schema: dict) -> list[str]:
    """Paths of every property (and every map's entry schema) that has no description of its own or via $ref."""
    missing: list[str] = []

    def walk(node, path: str) -> None:
        if not isinstance(node, dict):
            return
        for key, child in (node.get("properties") or {}).items():
            check(child, f"{path}.{key}" if path else key)
        entry = node.get("additionalProperties")
        if isinstance(entry, dict):
            check(entry, f"{path}.<entry>")
        if isinstance(node.get("items"), dict):
            walk(_resolve(schema, node["items"]), f"{path}[]")
        for name, sub in (node.get("$defs") or {}).items():
            walk(sub, f"$defs.{name}")

    def check(child, path: str) -> None:
        if not str(_resolve(schema, child).get("description", "")).strip():
            missing.append(path)
        walk(_resolve(schema, child), path)

    walk(schema, "")
    return missing


def test_committed_reference_is_up_to_date():
    expected = config_docs.render(*_inputs())
    committed = (REPO / "config" / "README.md").read_text() if (REPO / "config" / "README.md").is_file() else ""
    assert committed == expected, ("config/README.md is out of date with workflow/schemas/config.schema.yaml or "
                                   "config/config.yaml: run `.venv/bin/ocpipe config-docs`")


def test_every_schema_property_is_described():
    schema, _ = _inputs()
    missing = _undocumented(schema)
    assert not missing, "schema properties without a description:\n  " + "\n  ".join(missing)


def test_study_values_are_named_where_the_study_profile_differs():
    """Every key config/thesis.yaml sets to another value says the study's value: "(study: X)" on it or a parent."""
    schema, defaults = _inputs()
    thesis = yaml.safe_load((REPO / "config" / "thesis.yaml").read_text())
    silent = []

    def walk(value, default, node, path, said):
        node = _resolve(schema, node)
        said = said or "(study:" in node.get("description", "")
        if isinstance(value, dict) and isinstance(default, dict):
            for key, sub in value.items():
                child = (node.get("properties") or {}).get(key, node.get("additionalProperties"))
                walk(sub, default.get(key), child if isinstance(child, dict) else {}, f"{path}.{key}", said)
        elif value != default and not said:
            silent.append(f"{path.lstrip('.')}: study {value!r}, default {default!r}")

    walk(thesis, defaults, schema, "", False)
    assert not silent, "descriptions missing the study's value, as \"(study: X)\":\n  " + "\n  ".join(silent)


def test_render_lists_key_paths_with_their_defaults():
    schema, defaults = _inputs()
    text = config_docs.render(schema, defaults)
    rows = {line.split(" | ")[0].strip("| `"): line for line in text.splitlines() if line.startswith("| `")}
    assert "`residual`" in rows["policy.joint_targets"] and "`absolute`" in rows["policy.joint_targets"]
    assert f"`{defaults['evaluation']['stability_episodes']}`" in rows["evaluation.stability_episodes"]
    assert "`[0.4, 0.3, 0.5]`" in rows["cameras.side.eye"]  # $ref to $defs/camera, each site with its own values
    assert "`{goal: 2d, goal_calibration: exact, resolution: 224}`" in rows["experiments.goal2d_exact_224"]
    assert "any key of `policy`" in rows["experiments.<name>.*"]  # the policy keys reused through the YAML anchor
    assert "(optional)" in rows["compute.<stage>.gpu"]
    assert "\\|" in rows["encoders.slots_ssl.train_stores"]  # a pattern's '|' must not split the table cell
    assert text == config_docs.render(schema, defaults)  # deterministic
    for section in schema["properties"]:
        assert f"\n## {section}\n" in text


def test_cli_check_flags_a_stale_file(tmp_path, monkeypatch, capsys):
    stale = tmp_path / "README.md"
    stale.write_text("stale\n")
    monkeypatch.setattr(config_docs, "README_PATH", stale)
    assert cli.main(["config-docs", "--check"]) == 1
    assert "config/README.md is out of date: run `ocpipe config-docs`" in capsys.readouterr().err
    assert cli.main(["config-docs"]) == 0
    assert stale.read_text() == config_docs.render(*_inputs())  # exact: the same deterministic text rendering
    assert cli.main(["config-docs", "--check"]) == 0
    assert not list(tmp_path.glob(".tmp-*"))  # written through a temporary sibling, renamed into place
