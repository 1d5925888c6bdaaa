"""proprio.notebook: the notebooks' interact fails loudly on an error in its first call; html_iframe embeds a page."""
from __future__ import annotations

import html

import ipywidgets
import pytest

from proprio.notebook import html_iframe, interact


def test_interact_runs_with_the_defaults_and_returns_the_widget():
    seen = []
    w = interact(lambda x=2.0: seen.append(x) or x * 10, x=ipywidgets.FloatSlider(value=3.0, min=0, max=5))
    assert seen == [3.0] and w.result == 30.0


def test_interact_raises_what_the_callback_raised():
    def broken(x=1):
        raise KeyError(f"no such channel {x}")
    with pytest.raises(KeyError, match="no such channel 4"):
        interact(broken, x=ipywidgets.IntSlider(value=4))


def test_html_iframe_embeds_the_page_escaped():
    page = "<html><body><script>var s = \"a\" + 'b' & 1;</script></body></html>"
    out = html_iframe(page, height=300).data
    assert out.startswith('<div><iframe srcdoc="') and "height:300px" in out
    srcdoc = out[len('<div><iframe srcdoc="'):out.index('" style=')]
    assert '"' not in srcdoc and html.unescape(srcdoc) == page
