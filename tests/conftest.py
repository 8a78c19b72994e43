"""Fixtures shared by the test modules."""

import pytest


@pytest.fixture(scope="module")
def t():
    """The packaged template (facecorr.template.Template)."""
    from facecorr.template import load_template

    return load_template()
