"""Things the kart saw that were not there, driven again from the file of the sweep event that showed each
(tests/data/phantoms/, each file saying what was seen and what fixed it), as far as it showed: the rules must not
enter the state the phantom put them in. The whole events are the sweep's; these seconds are where they went wrong.
"""

from pathlib import Path

import pytest

from kartpilot.runtime.scenarios import run_scenario
from kartpilot.sim.scenarios import load_scenario_file

PHANTOMS = Path(__file__).resolve().parents[1] / "data" / "phantoms"
# each file: the seconds that held the phantom, and the state it called for
CASES = {"parking-10533": (1.0, "yield"), "overtake-10532": (1.2, "yield")}


@pytest.mark.parametrize("name", sorted(CASES))
def test_a_phantom_the_sweep_found_is_not_seen_again(name):
    seconds, state = CASES[name]
    result = run_scenario(load_scenario_file(PHANTOMS / f"{name}.yaml"), None, max_time_s=seconds)
    states = [row[1] for row in result["states"]]
    print(f"\n{name}, the first {seconds} s: {result['states']}")
    assert states and state not in states


def test_every_phantom_file_has_its_case():
    assert sorted(p.stem for p in PHANTOMS.glob("*.yaml")) == sorted(CASES)
