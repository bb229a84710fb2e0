"""The settings helpers: field docstrings read from the source (inherited ones too), integer checks
and building from a dict with unknown keys named."""

from __future__ import annotations

import dataclasses

import pytest

from bimgame.learn.a3c import A3CConfig
from bimgame.learn.common import NetworkSettings
from bimgame.util.settings import FieldDoc, field_docs, from_dict, require_int, split_field_doc


@dataclasses.dataclass(frozen=True)
class Base:
    size: int = 1
    """The size,
    over two lines   with   odd spacing."""
    colour: str = "red"
    """Base's colour."""
    plain: int = 0


@dataclasses.dataclass(frozen=True)
class Child(Base):
    colour: str = "blue"
    """Child's colour."""
    depth: int = 2
    """How deep."""
    note = "not a field"
    """Docstring of a class attribute that is no annotated field."""
    skipped: int = 5

    def method(self) -> None:
        """A method's docstring."""


def test_field_docs_folds_to_one_line_and_omits_undocumented_fields():
    docs = field_docs(Base)
    assert docs == {"size": "The size, over two lines with odd spacing.", "colour": "Base's colour."}


def test_field_docs_include_the_bases_and_the_subclass_overrides_them():
    docs = field_docs(Child)
    assert docs == {"size": "The size, over two lines with odd spacing.", "colour": "Child's colour.",
                    "depth": "How deep."}


def a3c_flat_docs() -> dict[str, str]:
    """The docstrings of every A3C setting by its flat name, each read from the part that holds it."""
    docs: dict[str, str] = {}
    for cls, names in A3CConfig.name_groups():
        part_docs = field_docs(cls)
        docs.update({name: part_docs[name] for name in names if name in part_docs})
    return docs


def test_field_docs_of_a3c_config_include_its_network_settings():
    docs = a3c_flat_docs()
    assert docs["obs"] == field_docs(NetworkSettings)["obs"]
    assert docs["obs"].startswith("Observation: ``pixels``")
    assert {"obs", "hidden", "features", "tilt_input", "keypoints", "subtract_background"} <= set(docs)
    assert docs["steps"] == "Environment steps to train for (all workers together)."
    assert all("\n" not in text and "  " not in text for text in docs.values())
    # every documented name is a setting (a flat name)
    assert set(docs) <= set(A3CConfig.flat_names())
    # a multi-line docstring is folded
    assert docs["envs_per_worker"].startswith("Environments per worker, stepped as one batch")
    assert "16." in docs["envs_per_worker"]


def test_field_docs_of_a_class_defined_in_a_function():
    @dataclasses.dataclass
    class Local:
        a: int = 1
        """Local a."""

    assert field_docs(Local) == {"a": "Local a."}


def test_field_docs_without_source_are_empty():
    made = dataclasses.make_dataclass("Made", [("x", int, dataclasses.field(default=1))])
    assert field_docs(made) == {}


@pytest.mark.parametrize("value, minimum", [(1, 1), (5, 1), (0, 0), (-3, -3)])
def test_require_int_accepts(value, minimum):
    require_int("Owner", "name", value, minimum)


@pytest.mark.parametrize("value", [0, -1, 1.0, 2.5, "3", None, True, False])
def test_require_int_refuses(value):
    with pytest.raises(ValueError) as error:
        require_int("Owner", "field", value, 1)
    message = str(error.value)
    assert "Owner.field" in message and "an integer >= 1" in message and repr(value) in message
    assert "None or" not in message


def test_require_int_refuses_a_bool_even_when_it_meets_the_minimum():
    with pytest.raises(ValueError, match="True"):
        require_int("Owner", "flag", True, 0)


def test_require_int_optional_accepts_none_and_says_so_when_refusing():
    require_int("Owner", "limit", None, 1, optional=True)
    require_int("Owner", "limit", 4, 1, optional=True)
    with pytest.raises(ValueError, match=r"Owner\.limit must be None or an integer >= 1, got 0"):
        require_int("Owner", "limit", 0, 1, optional=True)


def test_from_dict_builds_and_names_unknown_keys():
    assert from_dict(Child, {"depth": 7}, "child settings") == Child(depth=7)
    with pytest.raises(ValueError) as error:
        from_dict(Child, {"depth": 7, "zeta": 1, "alpha": 2}, "child settings")
    message = str(error.value)
    assert "unknown child settings ['alpha', 'zeta']" in message
    assert "'depth'" in message and "'size'" in message  # the allowed keys are listed


def test_from_dict_lets_the_class_validate():
    with pytest.raises(ValueError, match="NetworkSettings.hidden"):
        from_dict(NetworkSettings, {"hidden": 0}, "network settings")


@pytest.mark.parametrize("doc, text, none, false", [
    ("LSTM size; None: 256 for pixels (the paper's), 128 for state.", "LSTM size.",
     "256 for pixels (the paper's), 128 for state", None),
    ("Feed the tilt (see nets). False: the paper's exact input.", "Feed the tilt (see nets).", None,
     "the paper's exact input"),
    ("Preset (a: x; b: y); None: none (from scratch). See docs.", "Preset (a: x; b: y). See docs.",
     "none (from scratch)", None),
    ("Heads. None: on for pixels (1.5× faster; see x. y), off for state. False: no heads.", "Heads.",
     "on for pixels (1.5× faster; see x. y), off for state", "no heads"),
    ("Plain text, e.g. 5M. No clause here.", "Plain text, e.g. 5M. No clause here.", None, None),
    ("Time limit; None uses the task's.", "Time limit; None uses the task's.", None, None),
])
def test_split_field_doc_separates_the_value_clauses(doc, text, none, false):
    assert split_field_doc(doc) == FieldDoc(text=text, none=none, false=false)


def test_the_network_settings_none_clauses_name_the_values_the_class_fills_in():
    """``--help`` shows these clauses as the defaults of ``bimgame train``: they must agree with what
    the class fills in per observation mode."""
    docs = {name: split_field_doc(text) for name, text in field_docs(NetworkSettings).items()}
    for name in ("hidden", "features"):
        for obs in ("pixels", "state"):
            value = getattr(NetworkSettings(obs=obs), name)
            assert f"{value} for {obs}" in docs[name].none, (name, obs)
    for obs in ("pixels", "state"):
        on = "on" if NetworkSettings(obs=obs).aux_heads else "off"
        assert f"{on} for {obs}" in docs["aux_heads"].none
