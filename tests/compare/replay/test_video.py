"""The video: frame count and size, the panels' overlay content, a still, a missing encoder."""

from __future__ import annotations

import dataclasses
import math
import shutil

import imageio.v3 as iio
import imageio_ffmpeg
import numpy as np
import pytest
from typer.testing import CliRunner

from compare.cli import app
from compare.replay.exceptions import ReplayError
from compare.replay.overlay import ACTIVATION, CLEAR, PHYSICAL, SAFETY, UNKNOWN, PanelSource, margin_colour
from compare.replay.run_data import load_run
from compare.replay.video import VideoSettings, write_video

pytestmark = pytest.mark.rendering


def test_a_short_video_has_the_frames_and_size_asked_for(case2_run, tmp_path):
    out = tmp_path / "clip.mp4"
    args = ["replay", str(case2_run), "--video", str(out), "--fps", "10", "--from", "0.5", "--to", "1.7"]
    result = CliRunner().invoke(app, [*args, "--size", "320x192", "-q"])
    assert result.exit_code == 0, result.output
    frames, seconds = imageio_ffmpeg.count_frames_and_secs(str(out))
    assert frames == 12 and seconds == pytest.approx(1.2, abs=0.01)
    reader = imageio_ffmpeg.read_frames(str(out))
    meta = reader.__next__()
    assert meta["size"] == (320, 192) and meta["codec"] == "h264"
    first = np.frombuffer(next(reader), dtype=np.uint8).reshape(192, 320, 3)
    reader.close()
    assert first.std() > 10  # a picture, not a blank frame
    assert "12 frames, 320x192" in result.output


def test_frame_times_cover_the_window_at_the_rate():
    times = VideoSettings(fps=25).frame_times(2.0, 4.0)
    assert len(times) == 50 and times[0] == 2.0 and times[-1] == pytest.approx(3.96)
    with pytest.raises(ReplayError, match="even"):
        VideoSettings(width=321)


def test_the_overlay_shows_the_step_s_status_active_tasks_and_thresholds(case2_run):
    run = load_run(case2_run)
    mink = run.methods[1]
    source = PanelSource(run, mink)
    row = int(np.argmax(mink.steps["active:obstacle_link_7"].to_numpy(dtype=bool)))
    info = source.info(row, float(mink.t[row]))
    assert "obstacle_link_7" in info.active
    expected = {n.removeprefix("active:") for n in mink.steps.columns if n.startswith("active:") and mink.steps[n][row]}
    assert set(info.active) == expected
    assert info.status == mink.steps["status"][row]
    bar = info.distances[[b.frame for b in info.distances].index("link_7")]
    assert (bar.physical_m, bar.safety_m, bar.activation_m) == pytest.approx((0.1, 0.35, 0.40))
    assert bar.measured_m == pytest.approx(mink.steps["dist_meas:link_7"][row])
    assert source.info(len(mink.t) - 1, 10.0).status == "ended"


def test_margin_colours_follow_the_threshold_zones():
    limits = (0.1, 0.35, 0.4)
    assert margin_colour(0.05, *limits) == PHYSICAL
    assert margin_colour(0.2, *limits) == SAFETY
    assert margin_colour(0.3495, *limits) == ACTIVATION  # held at the threshold: not a violation
    assert margin_colour(0.38, *limits) == ACTIVATION
    assert margin_colour(0.6, *limits) == CLEAR
    assert margin_colour(math.inf, *limits) == UNKNOWN


def test_a_still_is_a_png_of_the_size_asked_for(case2_run, tmp_path):
    out = tmp_path / "still.png"
    result = CliRunner().invoke(
        app, ["replay", str(case2_run), "--still", str(out), "--from", "2", "--size", "640x360"]
    )
    assert result.exit_code == 0, result.output
    image = iio.imread(out)
    assert image.shape == (360, 640, 3)


def test_no_ffmpeg_is_one_line(case2_run, tmp_path, monkeypatch):
    def missing() -> str:
        raise RuntimeError("No ffmpeg exe could be found")

    monkeypatch.setattr(imageio_ffmpeg, "get_ffmpeg_exe", missing)
    with pytest.raises(ReplayError, match="no ffmpeg"):
        write_video(load_run(case2_run, t_to=0.2), tmp_path / "v.mp4")


@pytest.mark.slow
def test_segments_rendered_by_two_processes_join_into_one_video_of_every_frame(case2_run, tmp_path):
    out = tmp_path / "joined.mp4"
    run = load_run(case2_run)
    stats = write_video(run, out, VideoSettings(320, 192, 50.0), workers=2)  # 200 frames: two segments
    assert stats.workers == 2 and stats.frames == 200
    frames, seconds = imageio_ffmpeg.count_frames_and_secs(str(out))
    assert frames == 200 and seconds == pytest.approx(4.0, abs=0.03)
    assert not list(tmp_path.glob(".replay-*"))  # the segments are removed


def test_a_failing_worker_is_one_line(case2_run, tmp_path):
    run = load_run(case2_run)
    broken = tmp_path / "broken"
    shutil.copytree(case2_run, broken)
    moved = dataclasses.replace(run, run_dir=broken)
    shutil.rmtree(broken / "steps")  # the workers reload the run from its directory
    with pytest.raises(ReplayError, match="rendering .* failed: ReplayError: no per-step table"):
        write_video(moved, tmp_path / "v.mp4", VideoSettings(320, 192, 50.0), workers=2)
