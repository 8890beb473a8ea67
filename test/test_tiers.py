"""The test tiers' own machinery (test/conftest.py, tools/test.sh): what a wrong version broke."""

from __future__ import annotations

import os

import pytest


@pytest.mark.xdist_group("the guard")
def test_xdist_groups_hold(request: pytest.FixtureRequest) -> None:
    """Under `--dist loadgroup` a grouped test carries its group: pytest 9 with pytest-xdist 3.8
    dropped it without a word, and a README section's lines ran on different workers."""
    if os.environ.get("PYTEST_XDIST_WORKER") and request.config.getvalue("loadgroup"):
        assert request.node.nodeid.endswith("@the guard"), request.node.nodeid


@pytest.mark.fast_cases("kept")
@pytest.mark.parametrize("case", ["kept", "moved"])
def test_fast_cases_keep_only_the_named_cases(case: str, request: pytest.FixtureRequest) -> None:
    slow = request.node.get_closest_marker("slow") is not None
    assert slow == (case == "moved")
