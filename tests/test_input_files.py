"""YAML and JSON from users: bounded before anything walks them, errors that never quote the file.

Inputs are generated here: an alias bomb of 9 levels of 9 (9^9 = 387 million strings from a few
hundred bytes), nesting 10,000 deep, a parameter file shaped like /etc/shadow, a node parameter
file of 28,500 node sections (0.97 MiB). Each must end in one line within seconds.
"""

import time

import pytest

from prsm_ros.limits import YAML_MAX_DEPTH, YAML_MAX_EXPANDED, load_json, load_yaml

SHADOW = "root:$6$Qw8s9d$secrethashsecrethash:19000:0:99999:7:::\ndaemon:*:19000:0:99999:7:::\n"
SHADOW_LINES = [ln.split(":")[1] for ln in SHADOW.splitlines()] + ["root:", "daemon:"]


def alias_bomb(indent: str = "") -> str:
    """Nine levels, each a list of nine aliases of the level below: 530 bytes under `set:` in a study."""
    lines = [f'{indent}a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for k in range(1, 9):
        lines.append(f"{indent}a{k}: &a{k} [{', '.join(f'*a{k - 1}' for _ in range(9))}]")
    return "\n".join(lines) + "\n"


def test_an_alias_bomb_is_refused_before_anything_expands_it():
    t0 = time.monotonic()
    with pytest.raises(ValueError, match=f"more than {YAML_MAX_EXPANDED} nodes and characters"):
        load_yaml(alias_bomb(), source="bomb.yaml")
    assert time.monotonic() - t0 < 5


def test_deep_nesting_a_recursive_alias_and_two_documents_give_one_line():
    for text, says in (("[" * 500 + "]" * 500, f"nested more than {YAML_MAX_DEPTH} levels"),
                       ("[" * 10_000 + "]" * 10_000, "not valid YAML at line 1"),  # libyaml's own limit: 1000
                       ("a: &x [1, *x]", "an alias refers to a collection that contains it"),
                       ("a: 1\n---\nb: 2\n", "not valid YAML at line 2")):
        with pytest.raises(ValueError) as e:
            load_yaml(text, source="f.yaml")
        assert says in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(ValueError, match="JSON nested more than"):
        load_json("[" * 100_000, source="labels")
    assert load_yaml("a: &x [1, 2]\nb: *x\n", source="f") == {"a": [1, 2], "b": [1, 2]}


def test_a_study_with_an_alias_bomb_under_set_is_refused_quickly(tmp_path, capsys):
    """Was: `prsm-sweep` hung (study_hash's json.dumps expanded the aliases, past 2 GB after 120 s)."""
    from prsm_ros.cli.sweep import main
    study = tmp_path / "bomb.yaml"
    study.write_text("preset: s30\nscenario: step\nset:\n" + alias_bomb("  "), encoding="utf-8")
    assert len(study.read_bytes()) < 600
    t0 = time.monotonic()
    rc = main(["run", str(study), "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "expands to more than" in err, err
    assert time.monotonic() - t0 < 10


def _run_params(tmp_path, capsys, text: str) -> str:
    from prsm_ros.cli.sim import main
    path = tmp_path / "params.yaml"
    path.write_text(text, encoding="utf-8")
    rc = main(["run", "--params", str(path), "--duration", "0.01"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1, err
    return err


def test_deeply_nested_parameters_give_one_line_not_a_recursion_error(tmp_path, capsys):
    err = _run_params(tmp_path, capsys, "geometry:\n  lead: " + "[" * 500 + "]" * 500 + "\n")
    assert "nested more than" in err


@pytest.mark.parametrize("text", [SHADOW, "geometry:\n  pitch_m: 'root:$6$Qw8s9d$secrethashsecrethash'\n",
                                  "preset: 'daemon:*:19000:0:99999:7:::'\n"])
def test_parameter_errors_never_quote_the_file(tmp_path, capsys, text):
    """Was: `prsm-sim run --params /etc/shadow` printed the file's lines as unknown group names."""
    err = _run_params(tmp_path, capsys, text)
    assert not any(secret in err for secret in SHADOW_LINES), err
    assert "params.yaml" in err


def test_fmu_build_and_a_study_params_file_never_quote_it_either(tmp_path, capsys):
    from prsm_ros.fmu.cli import main as fmu_main
    from prsm_ros.sweep import study
    (tmp_path / "shadow").write_text(SHADOW, encoding="utf-8")
    rc = fmu_main(["build", "--params", str(tmp_path / "shadow"), "-o", str(tmp_path / "x.fmu")])
    err = capsys.readouterr().err
    assert rc == 2 and not any(s in err for s in SHADOW_LINES), err
    (tmp_path / "study.yaml").write_text("params: shadow\nscenario: step\n", encoding="utf-8")
    with pytest.raises(study.StudyError) as e:
        _, norm, _ = study.load(tmp_path / "study.yaml")
        study.base_params(norm)
    assert not any(s in str(e.value) for s in SHADOW_LINES), str(e.value)


def test_a_node_parameter_file_of_28500_sections_is_refused_quickly(tmp_path):
    """Was: 777 MB and 10 s in the node before it refused the file."""
    from prsm_ros.limits import NODE_PARAMS_MAX_SECTIONS
    from prsm_ros.node.parameters import ConfigError, param_sources
    path = tmp_path / "many.yaml"
    path.write_text("".join(f"n{k:05d}:\n  ros__parameters:\n    g: 1\n" for k in range(28_500)),
                    encoding="utf-8")
    assert 0.9 < path.stat().st_size / 2**20 < 1.0
    t0 = time.monotonic()
    with pytest.raises(ConfigError) as e:
        param_sources(["--ros-args", "--params-file", str(path)], "prsm_actuator")
    assert time.monotonic() - t0 < 5
    assert f"more than {NODE_PARAMS_MAX_SECTIONS} top-level entries" in str(e.value)
    assert "\n" not in str(e.value)
