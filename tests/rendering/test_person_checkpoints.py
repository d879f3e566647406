"""Which human checkpoint draws each person of a render: the scenario's ``humans[k].appearance``, else k mod M."""

from __future__ import annotations

import pytest

from nsim.errors import InputError, WorkspaceError
from nsim.rendering.people import HumanSet, person_checkpoints

IDS = ("aaa111", "bbb222", "ccc333")
NAMES = {"human/a": "aaa111", "human/b": "bbb222", "human/c": "ccc333", "bbb": "bbb222", "human/other": "ddd444"}


def find(name: str) -> str | None:
    if name == "human/dangling":
        raise WorkspaceError("ref human/dangling points at eee555, which is not in the workspace")
    if name == "ab":
        raise InputError("artifact prefix ab is ambiguous: ab1, ab2; give more digits")
    return NAMES.get(name)


def test_named_people_get_their_checkpoint_the_others_k_mod_m():
    assert person_checkpoints(["", "", "", "", ""], IDS, find) == [0, 1, 2, 0, 1]
    assert person_checkpoints([None, "human/c", "", "bbb", "human/a"], IDS, find) == [0, 2, 2, 1, 0]
    assert person_checkpoints([], IDS, find) == []


def test_a_name_this_workspace_lacks_is_a_warning_and_k_mod_m(caplog):
    """Scenario files travel between workspaces (spot_run names human/ana ...): unknown names fall back, loudly."""
    with caplog.at_level("WARNING"):
        assert person_checkpoints(["human/ana", "human/b", "human/ben"], IDS, find, source="trajectory 123") == [0, 1, 2]
    assert "humans[0] 'human/ana', humans[2] 'human/ben'" in caplog.text and "k mod 3" in caplog.text


@pytest.mark.parametrize(("name", "message"), [
    ("human/other", r"humans\[1\]\.appearance 'human/other' is human checkpoint ddd444, which is not among the "
                    r"render's --humans \(aaa111, bbb222, ccc333\): add it"),
    ("ab", r"humans\[1\]\.appearance 'ab': artifact prefix ab is ambiguous"),
    ("human/dangling", r"humans\[1\]\.appearance 'human/dangling': ref human/dangling points at eee555"),
])
def test_bad_names_are_one_line_naming_the_person(name, message):
    with pytest.raises(InputError, match=r"^trajectory 123: " + message) as err:
        person_checkpoints(["", name, ""], IDS, find, source="trajectory 123")
    assert "\n" not in str(err.value)


def test_no_checkpoint_at_all_is_refused():
    with pytest.raises(InputError, match="at least one human checkpoint"):
        person_checkpoints(["", ""], (), find)


def test_human_set_draws_each_person_with_its_checkpoint():
    models = ["m0", "m1", "m2"]
    assert [HumanSet(models, {}, "cpu").model_index(k) for k in range(5)] == [0, 1, 2, 0, 1]
    chosen = HumanSet(models, {}, "cpu", person_model=[2, 2, 0, 1, 0])
    assert [chosen.model_index(k) for k in range(5)] == [2, 2, 0, 1, 0]
