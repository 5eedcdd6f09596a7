"""Figure titles: a composite model's long name is broken into lines that fit the figure."""

from __future__ import annotations

import numpy as np
import pytest

from bayeshyst.plotting._common import new_figure, wrap_title

#: The final model of the MR damper's diagnosis at 0 A: its title line was cut off at
#: both edges of the 10 in residual figure.
MR_FINAL = ("after: bouc_wen(sign=1, parametrisation='saturation')+aux(column='velocity_mm_s')"
            "+creep+unexplained(feature=velocity_mm_s)+drift with discrepancy hsgp")
BLOCKS = ["creep", "delay(max_delay_samples=10)", "asym_output(order=2)", "drift",
          "aux(column='temperature_c')", "second_order", "unexplained(feature=time)",
          "disturbance(frequency_hz=7.64334)", "change_point"]


def _names(seed, n=20):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        k = int(rng.integers(1, len(BLOCKS) + 1))
        blocks = rng.choice(BLOCKS, size=k, replace=False)
        yield "model: bouc_wen(sign=1, parametrisation='saturation')+" + "+".join(blocks)


def _pieces(line):
    # the break opportunities, found independently of the wrapper: before every '+',
    # after every run of spaces
    out, cur = [], ""
    for i, ch in enumerate(line):
        if ch == "+" and cur:
            out.append(cur)
            cur = ""
        elif i and line[i - 1] == " " and ch != " " and cur:
            out.append(cur)
            cur = ""
        cur += ch
    return [*out, cur]


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("width_in", [4.0, 6.0, 10.0])
def test_wrapped_lines_fit_lose_nothing_and_are_full(seed, width_in):
    fig = new_figure(None, width_in, 2.0)
    width = int(width_in * 72.0 / (0.62 * 10.0))
    for name in _names(seed):
        out = wrap_title(name, fig).split("\n")
        # nothing lost: the lines are the name cut at break points (spaces at a cut dropped)
        assert "".join(out).replace(" ", "") == name.replace(" ", "")
        pos = 0
        for i, line in enumerate(out):
            # every line fits, unless it is one piece that cannot be broken
            assert len(line) <= width or len(_pieces(line)) == 1, (line, width)
            start = name.index(line, pos)
            assert name[pos:start].strip() == ""  # only spaces dropped at a cut
            pos = start + len(line)
            # greedy: the next line's first piece would not have fitted on this one
            if i + 1 < len(out):
                gap = len(name[pos:]) - len(name[pos:].lstrip(" "))
                nxt = _pieces(out[i + 1])[0].rstrip()
                assert len(line) + gap + len(nxt) > width, (line, nxt, width)
        assert pos == len(name)
        assert len(out) == 1 or len(name) > width


def test_short_lines_and_line_breaks_are_kept():
    fig = new_figure(None, 10.0, 2.0)
    text = "diagnosis: effects found: creep\nbefore: bouc_wen\nafter: bouc_wen+creep"
    assert wrap_title(text, fig) == text


def test_the_wrapped_title_fits_inside_the_rendered_figure():
    fig = new_figure(None, 10.0, 3.0)
    fig.add_subplot()
    sup = fig.suptitle(MR_FINAL, fontsize=10)
    fig.canvas.draw()
    box = sup.get_window_extent(fig.canvas.get_renderer())
    # the case means something: unwrapped, the line runs off the figure
    assert box.width > fig.bbox.width
    sup.set_text(wrap_title(MR_FINAL, fig, fontsize=10))
    fig.canvas.draw()
    box = sup.get_window_extent(fig.canvas.get_renderer())
    assert 0.0 <= box.x0 and box.x1 <= fig.bbox.width
    assert sup.get_text().count("\n") == 1
