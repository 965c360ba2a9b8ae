"""benchmarks/card.py: a benchmark's figures go into the model's card without losing what it held."""

from __future__ import annotations

import datetime
import json
from pathlib import Path

import pytest
from helpers import benchmark_module

ROOT = Path(__file__).resolve().parents[1]


def test_figures_join_the_card_beside_what_it_held(tmp_path):
    card = benchmark_module("card")
    model = tmp_path / "m.pt"
    (tmp_path / "m.json").write_text(json.dumps({"model": "m.pt", "epochs": 3, "measured": {"old": {"x": 1}}}))
    path = card.record(model, "demo_model", {"mean_deg": 10.5}, "python benchmarks/demo_model.py --card")
    assert path == tmp_path / "m.json"
    got = json.loads(path.read_text())
    assert got["model"] == "m.pt" and got["epochs"] == 3  # what train_demo wrote stays
    assert got["measured"]["old"] == {"x": 1}  # another benchmark's entry stays
    today = datetime.date.today().isoformat()
    assert got["measured"]["demo_model"] == {
        "command": "python benchmarks/demo_model.py --card",
        "date": today,
        "mean_deg": 10.5,
    }
    card.record(model, "demo_model", {"mean_deg": 9.0}, "c")  # a rerun replaces its own entry
    got = json.loads(path.read_text())
    assert got["measured"]["demo_model"]["mean_deg"] == 9.0 and got["measured"]["old"] == {"x": 1}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.json"]  # no temporary file left


def test_a_model_without_a_card_gets_one_and_a_broken_card_is_refused_untouched(tmp_path):
    card = benchmark_module("card")
    path = card.record(tmp_path / "new.pt", "track_accuracy", {"people": 4}, "c")
    assert json.loads(path.read_text())["measured"]["track_accuracy"]["people"] == 4
    broken = tmp_path / "b.json"
    broken.write_text("{not json")
    with pytest.raises(card.CardError, match=r"b\.json: the model card is not readable JSON"):
        card.record(tmp_path / "b.pt", "demo_model", {}, "c")
    assert broken.read_text() == "{not json"
    (tmp_path / "l.json").write_text("[1, 2]")
    with pytest.raises(card.CardError, match="must be a JSON object, got list"):
        card.record(tmp_path / "l.pt", "demo_model", {}, "c")


def test_the_scripts_say_a_broken_card_in_one_line_and_exit_2(tmp_path, capsys):
    card = benchmark_module("card")
    (tmp_path / "b.json").write_text("{not json")
    with pytest.raises(SystemExit) as exc:
        card.record_or_exit(tmp_path / "b.pt", "demo_model", {}, "c")
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "b.json" in err[0]
    card.record_or_exit(tmp_path / "g.pt", "demo_model", {"x": 1}, "c")
    assert capsys.readouterr().err.strip() == f"recorded in {tmp_path / 'g.json'}"


def test_a_model_inside_the_repository_is_named_relative_to_it(tmp_path):
    card = benchmark_module("card")
    assert card.shown(ROOT / "gazeaug" / "models" / "demo_wheelchair.pt") == "gazeaug/models/demo_wheelchair.pt"
    assert card.shown(tmp_path / "m.pt") == str(tmp_path / "m.pt")
