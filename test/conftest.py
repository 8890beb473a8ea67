"""Shared fixtures: the paper's three fins."""

from __future__ import annotations

import pytest

from piezofin_ros.fin import Fin, load_fin

PAPER_FINS = ("M8507-P1", "M8514-P1", "M8528-P1")


@pytest.fixture(params=PAPER_FINS)
def paper_fin(request: pytest.FixtureRequest) -> Fin:
    return load_fin(request.param)


@pytest.fixture
def m8528() -> Fin:
    return load_fin("M8528-P1")
