"""Round progress bars: the postfix always current, the bar redrawn at most every REDRAW_S."""

import io
import time

from tqdm import tqdm

from adademo_lerobot.core.progress import REDRAW_S, show


def test_a_bar_is_redrawn_at_most_every_redraw_interval_and_keeps_the_latest_postfix():
    out = io.StringIO()
    bar = tqdm(total=3, file=out, mininterval=0, dynamic_ncols=False, ncols=200)
    drawn = out.getvalue().count("\r")
    for k in range(200):
        show(bar, task="push-v3", demos=k)
    assert out.getvalue().count("\r") - drawn <= 2  # 200 updates within far less than a few REDRAW_S
    assert bar.postfix == "task=push-v3, demos=199"
    time.sleep(REDRAW_S * 1.5)
    show(bar, task="reach-v3", demos=7)
    assert out.getvalue().rstrip().endswith("task=reach-v3, demos=7]")  # drawn once the interval passed
    bar.close()
