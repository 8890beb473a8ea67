"""The trials' table and plot as a person reads them (``control/report.py``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
import pytest

from piezofin_ros.control import report
from piezofin_ros.physics.amplifier import PAPER_BENCH, power_in
from piezofin_ros.physics.model import Model, load_model

matplotlib.use("Agg")


@pytest.mark.parametrize("name", ["paper-twin-M8528-P1", ""])
def test_the_trials_plot_draws_the_model_that_ran_and_names_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, name: str
) -> None:
    """The lines under the trials are the model that ran (the twin's 3.6 mN at 4 Hz, not the nominal
    fin's 17 mN at 10 Hz under them), named in every panel's legend, in the watt the plot names."""
    import matplotlib.pyplot as plt

    model = load_model(name) if name else Model(load_model("paper-twin-M8528-P1").fin)
    kept: list[Any] = []
    monkeypatch.setattr(plt, "close", kept.append)  # (keep the figure to read it back)
    f = np.array([2.0, 4.0, 6.0])
    pred = model.predict(f, np.full(3, 800.0))
    supply = power_in("supply", pred.voltage_pp_drive, pred.current_rms, pred.power_w, PAPER_BENCH)
    records = [
        {
            "trial": k,
            "frequency_hz": float(f[k]),
            "voltage_pp": 800.0,
            "thrust_n": float(pred.thrust_n[k]),
            "thrust_loadcell_n": float(pred.thrust_n[k]),
            "power_supply_w": float(supply[k]),
            "thrust_per_watt_supply": float(pred.thrust_n[k] / supply[k]),
        }
        for k in range(3)
    ]
    out = report.plot_trials(tmp_path / "t.png", model, records, records[1], "", "supply", PAPER_BENCH, name)
    assert out.stat().st_size > 0
    (fig,) = kept
    thrust, power, per_watt = fig.axes
    for ax in fig.axes:
        labels = [t.get_text() for t in ax.get_legend().get_texts()]
        assert any(label.startswith(name or "the paper's model") for label in labels), labels
    line = thrust.get_lines()[0]  # the model's curve: it passes through the model's own points
    assert np.interp(f, *line.get_data()) == pytest.approx(pred.thrust_n * 1e3, rel=2e-3)
    assert "supply watt" in power.get_ylabel() and "supply watt" in per_watt.get_ylabel()
