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
