"""Names of bundled weights: "paper-tr0".."paper-tr4" always load the paper's models, whatever the defaults."""

import pytest

from jaxsr.io.checkpoint import BUNDLED_ALIASES, resolve_model_path


@pytest.mark.parametrize("tr", range(5))
def test_paper_names_resolve_to_the_papers_weights(tr):
    assert BUNDLED_ALIASES[f"paper-tr{tr}"] == f"tr{tr}"
    assert resolve_model_path(f"paper-tr{tr}") == resolve_model_path(f"tr{tr}")


def test_an_unknown_name_says_where_it_looked():
    with pytest.raises(FileNotFoundError, match="paper-tr9"):
        resolve_model_path("paper-tr9")


@pytest.mark.parametrize("name", ["tr0-photons", "tr4-photons"])
def test_bundled_photon_models_read_photons_and_mark_no_return(name):
    from jaxsr.io.checkpoint import read_metadata

    meta = read_metadata(resolve_model_path(name))
    assert meta["config"]["inputs"] == ["depth", "signal", "background"] and meta["config"]["no_return_head"]
    card = meta["card"]
    # the first stage of its training started from the paper's network of the same TR
    first = (card.get("earlier_stages") or [card])[0]
    assert card["regime"]["paper_prob"] > 0 and first["init"] == name.split("-")[0]


@pytest.mark.parametrize("name", ["tr0-ambient", "tr4-ambient"])
def test_bundled_ambient_models_continue_the_photon_models(name):
    from jaxsr.io.checkpoint import read_metadata

    meta = read_metadata(resolve_model_path(name))
    assert meta["config"]["inputs"] == ["depth", "signal", "background", "ambient"]
    assert meta["config"]["no_return_head"]
    card = meta["card"]
    # widened from the photon model of the same TR (itself from the paper's network), whose stages it lists
    # before its own, oldest first, with the steps of them all
    stages = [*card["earlier_stages"], card]
    assert name.replace("ambient", "photons") in [s["init"] for s in stages] and card["regime"]["snr_range"][1] > 20
    assert stages[0]["init"] == name.split("-")[0]
    assert card["total_steps"] == sum(s["steps"] for s in stages)


def test_an_empty_name_is_refused_with_what_is_expected():
    with pytest.raises(FileNotFoundError, match="bundled weights"):
        resolve_model_path("")
