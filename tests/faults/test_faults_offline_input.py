"""Bad offline input (issue #31, point 5 and the lazy synthetic source of point 4).

Each case gets one clear error line naming what was wrong, raised before any frame is processed
where the problem can be checked up front; damaged input loses only the frames that are damaged,
says so, and keeps everything computed.
"""

from __future__ import annotations

import errno
import os
import struct
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from gldt_core.cli import main
from gldt_core.io.mot import read_mot
from gldt_core.io.sources import open_source, source_kind
from gldt_core.io.video import VideoSource
from gldt_core.system.config import load_config

SYNTH = "synth:seed=1,frames=4,size=320x240"


def run_cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(argv)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def error_line(err: str) -> str:
    """The one line the CLI printed (the test fails when there is more than one)."""
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, f"expected one error line, got: {err!r}"
    return lines[0]


@pytest.fixture
def no_processing(monkeypatch: pytest.MonkeyPatch) -> None:
    """Fail the test if ``gldt run`` starts processing frames."""
    import gldt_core.system.runner as runner

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("processing started before the bad input was reported")

    monkeypatch.setattr(runner, "run_frames", refuse)


# ----------------------------------------------------------------------------- 1: --image-size


@pytest.mark.parametrize("size", [("0", "0"), ("640", "0"), ("-1", "480")])
def test_track_image_size_must_be_positive(tmp_path: Path, capsys: pytest.CaptureFixture[str], size) -> None:
    dets = tmp_path / "det.txt"
    dets.write_text("1,-1,10,10,5,5,0.9\n2,-1,11,11,5,5,0.9\n")
    out = tmp_path / "tracks.txt"
    code, _, err = run_cli(["track", "--dets", str(dets), "--out", str(out), "--image-size", *size], capsys)
    assert code == 2
    line = error_line(err)
    assert "--image-size" in line and f"{size[0]} {size[1]}" in line
    assert not out.exists()


def test_track_out_folder_fails_before_tracking(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    dets = tmp_path / "det.txt"
    dets.write_text("1,-1,10,10,5,5,0.9\n")
    code, _, err = run_cli(["track", "--dets", str(dets), "--out", str(tmp_path)], capsys)
    assert code == 2
    assert "--out" in error_line(err) and "is a folder" in err


# ------------------------------------------------------------------- 2: tracker parameter types


@pytest.mark.parametrize(
    ("yaml_text", "key", "expected"),
    [
        ('tracker: {name: jptrack, jptrack: {t_h: "high"}}', "tracker.jptrack.t_h", "expected float"),
        ("tracker: {jptrack: {history_len: 3.5}}", "tracker.jptrack.history_len", "expected int"),
        ("tracker: {bytetrack: {fuse_score: 1}}", "tracker.bytetrack.fuse_score", "expected bool"),
        ("tracker: {jptrack: {use_pmr: null}}", "tracker.jptrack.use_pmr", "expected bool"),
        ("tracker: {jptrack: {image_size: [0, 480]}}", "tracker.jptrack.image_size", "positive int"),
        ("tracker: {name: bytetrack, params: {track_thresh: [1]}}", "tracker.params.track_thresh", "expected float"),
        ("tracker: {name: bytetrack, params: {t_h: 0.3}}", "tracker.params.t_h", "unknown bytetrack parameter"),
    ],
)
def test_wrong_tracker_parameter_type_names_key_and_type(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], no_processing: None, yaml_text: str, key: str, expected: str
) -> None:
    config = tmp_path / "cfg.yaml"
    config.write_text(yaml_text + "\n")
    out = tmp_path / "tracks.txt"
    code, _, err = run_cli(["run", "--video", SYNTH, "--out", str(out), "--config", str(config)], capsys)
    assert code == 2
    line = error_line(err)
    assert key in line and expected in line and "cfg.yaml" in line
    assert "not supported" not in line
    assert not out.exists()


def test_valid_tracker_overrides_are_kept_with_their_field_types(tmp_path: Path) -> None:
    config = tmp_path / "cfg.yaml"
    config.write_text("tracker: {jptrack: {t_h: 1, history_len: 12, use_pmr: false, image_size: [640, 480]}}\n")
    params = load_config(config).tracker.parameters()
    assert params == {"t_h": 1.0, "history_len": 12, "use_pmr": False, "image_size": (640, 480)}
    assert isinstance(params["t_h"], float)


# ------------------------------------------------------- 3: image folders and unreadable images


def write_images(folder: Path, count: int, names: list[str] | None = None, size: tuple[int, int] = (96, 64)) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for k in range(count):
        image = np.full((size[1], size[0], 3), 20 * k % 250, np.uint8)
        name = names[k] if names else f"{k:04d}.jpg"
        assert cv2.imwrite(str(folder / name), image)


def test_plain_image_folder_is_a_source_sorted_by_name(tmp_path: Path) -> None:
    folder = tmp_path / "shots"
    names = ["b_002.png", "a_010.jpg", "c_001.bmp", "a_009.jpeg"]
    write_images(folder, 4, names)
    (folder / "notes.txt").write_text("not an image")
    assert source_kind(folder) == "images"
    source = open_source(folder)
    frames = list(source)
    assert len(source) == 4 and source.size == (96, 64)
    assert [f.index for f in frames] == [0, 1, 2, 3]
    # name order: a_009.jpeg, a_010.jpg, b_002.png, c_001.bmp (grey level 20 * position in `names`)
    assert [int(f.image[0, 0, 0]) for f in frames] == [60, 20, 0, 40]
    assert source.lost_frames == 0


def test_empty_folder_is_refused_with_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "empty"
    folder.mkdir()
    code, _, err = run_cli(["run", "--frames", str(folder), "--out", str(tmp_path / "t.txt")], capsys)
    assert code == 2
    assert "folder of images" in error_line(err)


@pytest.mark.parametrize("layout", ["plain", "mot"])
def test_unreadable_jpeg_skips_one_frame_with_a_warning(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, layout: str
) -> None:
    root = tmp_path / "seq"
    images = root if layout == "plain" else root / "img1"
    write_images(images, 6)
    if layout == "mot":
        (root / "seqinfo.ini").write_text("[Sequence]\nname=seq\nimDir=img1\nframeRate=10\nseqLength=6\nimExt=.jpg\n")
    bad = images / "0003.jpg"
    bad.write_bytes(bad.read_bytes()[:40])  # a cut JPEG: header only
    source = open_source(root)
    with caplog.at_level("WARNING"):
        frames = list(source)
    assert [f.index for f in frames] == [0, 1, 2, 4, 5]
    fps = source.fps
    assert [f.stamp for f in frames] == pytest.approx([k / fps for k in (0, 1, 2, 4, 5)])
    assert source.lost_frames == 1
    warnings = warning_lines(caplog)
    assert len(warnings) == 1 and "0003.jpg" in warnings[0]


def warning_lines(caplog: pytest.LogCaptureFixture) -> list[str]:
    """The warnings logged while ``gldt run`` ran (they go to stderr outside pytest)."""
    return [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]


def test_run_over_an_image_folder_with_a_bad_image_keeps_the_rest(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    folder = tmp_path / "frames"
    write_images(folder, 5, size=(160, 120))
    (folder / "0002.jpg").write_bytes(b"\xff\xd8\xff\xe0 not a jpeg")
    out = tmp_path / "tracks.txt"
    code, stdout, err = run_cli(["run", "--frames", str(folder), "--out", str(out), "--no-progress"], capsys)
    assert code == 3
    assert out.is_file()
    assert "4 frames" in stdout and "1 frame of the input could not be read" in stdout
    warnings = warning_lines(caplog)
    assert len(warnings) == 1 and "0002.jpg" in warnings[0]


# --------------------------------------------------------------------------- 4: output paths


def unwritable_folder(tmp_path: Path) -> Path:
    """A folder nobody may write in: a read-only one for a normal user; /sys for root."""
    if os.geteuid() != 0:
        folder = tmp_path / "readonly"
        folder.mkdir()
        folder.chmod(0o500)
        return folder
    if not os.access("/sys", os.F_OK):
        pytest.skip("running as root without /sys: no folder is read-only to this test")
    return Path("/sys")


@pytest.mark.parametrize("case", ["trailing-slash", "existing-folder", "under-a-file", "read-only", "missing-ro"])
def test_bad_out_path_fails_before_processing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], no_processing: None, case: str
) -> None:
    (tmp_path / "out_dir").mkdir()
    (tmp_path / "a_file").write_text("x")
    target = {
        "trailing-slash": str(tmp_path / "new_dir") + "/",
        "existing-folder": str(tmp_path / "out_dir"),
        "under-a-file": str(tmp_path / "a_file" / "tracks.txt"),
        "read-only": str(unwritable_folder(tmp_path) / "tracks.txt"),
        "missing-ro": str(unwritable_folder(tmp_path) / "sub" / "tracks.txt"),
    }[case]
    code, _, err = run_cli(["run", "--video", SYNTH, "--out", target, "--no-progress"], capsys)
    assert code == 2
    line = error_line(err)
    assert line.startswith("gldt run: error: --out ") and target in line
    assert not Path(target + ".part").exists()


@pytest.mark.parametrize("option", ["--plot", "--render"])
def test_unwritable_plot_or_render_fails_before_processing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], no_processing: None, option: str
) -> None:
    target = str(unwritable_folder(tmp_path) / ("run.png" if option == "--plot" else "run.mp4"))
    out = tmp_path / "tracks.txt"
    code, _, err = run_cli(["run", "--video", SYNTH, "--out", str(out), option, target, "--no-progress"], capsys)
    assert code == 2
    assert option in error_line(err) and target in err
    assert not out.exists()


def test_tracks_write_failing_at_the_end_leaves_no_part_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "tracks.txt"
    real_replace = os.replace

    def full_disk(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
        if Path(dst) == out:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", full_disk)
    code, _, err = run_cli(["run", "--video", SYNTH, "--out", str(out), "--no-progress"], capsys)
    assert code == 2
    line = error_line(err)
    assert "--out" in line and "No space left" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_plot_failing_at_the_end_keeps_the_tracks(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import gldt_core.viz.render as viz

    plot = tmp_path / "run.png"

    def failing_plot(path: str | os.PathLike[str], *args: object, **kwargs: object) -> None:
        Path(path).with_name("run.part.png").write_bytes(b"half a png")
        raise OSError(errno.EIO, os.strerror(errno.EIO))

    monkeypatch.setattr(viz, "save_run_plot", failing_plot)
    out = tmp_path / "tracks.txt"
    code, stdout, err = run_cli(
        ["run", "--video", SYNTH, "--out", str(out), "--plot", str(plot), "--no-progress"], capsys
    )
    assert code == 2
    line = error_line(err)
    assert "--plot" in line and "tracks were written" in line
    assert out.is_file() and "4 frames" in stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tracks.txt"]


# ------------------------------------------------------------------------------ 5: damaged video


def write_video(path: Path, fourcc: str, frames: int = 20, size: tuple[int, int] = (160, 120)) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*fourcc), 30.0, size)
    assert writer.isOpened()
    rng = np.random.default_rng(0)
    for k in range(frames):
        image = np.full((size[1], size[0], 3), 90, np.uint8)
        cv2.rectangle(image, (5 + 5 * k, 40), (20 + 5 * k, 55), (20, 20, 20), -1)
        writer.write(cv2.add(image, rng.integers(0, 40, image.shape, dtype=np.uint8)))
    writer.release()


def avi_frame_chunks(data: bytes) -> list[tuple[int, int]]:
    """(payload offset, size) of each ``00dc`` video chunk in an AVI's ``movi`` list."""
    position = data.index(b"movi") + 4
    chunks = []
    while position + 8 <= len(data):
        fourcc, size = data[position : position + 4], struct.unpack("<I", data[position + 4 : position + 8])[0]
        if fourcc == b"idx1":
            break
        if fourcc == b"00dc":
            chunks.append((position + 8, size))
        position += 8 + size + (size & 1)
    return chunks


def corrupt_avi(tmp_path: Path, bad_frame: int) -> Path:
    """A 20-frame MJPG AVI whose frame ``bad_frame`` (0-based) has its JPEG tables and the first half
    of its data overwritten (damage in the entropy-coded data alone is concealed by the decoder)."""
    path = tmp_path / "damaged.avi"
    write_video(path, "MJPG")
    data = bytearray(path.read_bytes())
    chunks = avi_frame_chunks(bytes(data))
    assert len(chunks) == 20
    start, size = chunks[bad_frame]
    data[start + 100 : start + size // 2] = b"\x5a" * (size // 2 - 100)
    path.write_bytes(bytes(data))
    return path


def faststart(data: bytes) -> bytes:
    """An MP4 with its ``moov`` box moved before ``mdat`` (chunk offsets shifted), as streamed MP4s are."""
    boxes, position = [], 0
    while position < len(data):
        size = struct.unpack(">I", data[position : position + 4])[0]
        boxes.append((data[position + 4 : position + 8], data[position : position + size]))
        position += size
    moov = bytearray(dict(boxes)[b"moov"])
    at = moov.find(b"stco")
    while at != -1:
        count = struct.unpack(">I", moov[at + 8 : at + 12])[0]
        for entry in range(count):
            field = at + 12 + 4 * entry
            moov[field : field + 4] = struct.pack(">I", struct.unpack(">I", moov[field : field + 4])[0] + len(moov))
        at = moov.find(b"stco", at + 12 + 4 * count)
    out = b""
    for kind, box in boxes:
        if kind != b"moov":
            out += box + (bytes(moov) if kind == b"ftyp" else b"")
    return out


def cut_mp4(tmp_path: Path) -> Path:
    whole = tmp_path / "whole.mp4"
    write_video(whole, "mp4v")
    data = faststart(whole.read_bytes())
    path = tmp_path / "cut.mp4"
    path.write_bytes(data[: len(data) // 2])
    return path


def test_healthy_video_reads_every_frame_and_loses_none(tmp_path: Path) -> None:
    path = tmp_path / "clip.avi"
    write_video(path, "MJPG")
    source = VideoSource(path)
    assert [f.index for f in source] == list(range(20))
    assert source.lost_frames == 0


def test_corrupt_avi_frame_is_skipped_and_reading_goes_on(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = corrupt_avi(tmp_path, bad_frame=5)
    source = VideoSource(path)
    with caplog.at_level("WARNING"):
        indices = [f.index for f in source]
    assert indices == [k for k in range(20) if k != 5]
    assert source.lost_frames == 1
    warnings = warning_lines(caplog)
    assert len(warnings) == 1 and "damaged.avi" in warnings[0] and "1 of 20" in warnings[0]
    assert "frame 6" in warnings[0]


def test_cut_mp4_reports_the_frames_it_lost(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = cut_mp4(tmp_path)
    gt = tmp_path / "gt.txt"
    gt.write_text("".join(f"{k},1,10,40,15,15,1,1,1,-1\n" for k in range(1, 21)))
    source = VideoSource(path, gt)
    assert len(source) == 20
    with caplog.at_level("WARNING"):
        frames = list(source)  # no error at the end: the gt's frames past the cut are lost frames
    assert 0 < len(frames) < 20
    assert [f.index for f in frames] == list(range(len(frames)))
    assert source.lost_frames == 20 - len(frames)
    warnings = warning_lines(caplog)
    assert len(warnings) == 1 and f"ended after frame {len(frames)} of 20" in warnings[0]


@pytest.mark.parametrize("damage", ["corrupt-avi", "cut-mp4"])
def test_run_over_damaged_video_keeps_going_and_exits_3(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture, damage: str
) -> None:
    path = corrupt_avi(tmp_path, bad_frame=5) if damage == "corrupt-avi" else cut_mp4(tmp_path)
    read = sum(1 for _ in VideoSource(path))
    caplog.clear()
    out = tmp_path / "tracks.txt"
    code, stdout, err = run_cli(["run", "--video", str(path), "--out", str(out), "--no-progress"], capsys)
    assert code == 3
    assert f"gldt run: {read} frames" in stdout
    lost = 20 - read
    assert f"{lost} frame{'s' if lost != 1 else ''} of the input could not be read" in stdout
    warnings = warning_lines(caplog)
    assert len(warnings) == 1 and path.name in warnings[0]
    assert out.is_file()
    tracks = read_mot(out)
    assert len(tracks) == 0 or tracks[:, 0].max() <= 20


# --------------------------------------------------------------------- 6: lazy synthetic source


def test_huge_synthetic_scene_reads_two_frames_fast_in_bounded_memory(tmp_path: Path) -> None:
    out = tmp_path / "tracks.txt"
    script = textwrap.dedent(
        f"""
        import resource, sys
        resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))
        from gldt_core.cli import main
        sys.exit(main(["run", "--video", "synth:seed=1,frames=999999999,size=640x360", "--max-frames", "2",
                       "--out", {str(out)!r}, "--no-progress"]))
        """
    )
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    seconds = time.perf_counter() - start
    assert done.returncode == 0, done.stderr[-2000:]
    assert "gldt run: 2 frames" in done.stdout
    assert seconds < 60
    tracks = read_mot(out)
    assert len(tracks) == 0 or set(tracks[:, 0].astype(int)) <= {1, 2}


def test_long_scene_is_made_of_shots_and_its_first_shot_is_the_short_scene() -> None:
    from gldt_core.sim.render import SceneRenderer
    from gldt_core.sim.scene_geometry import SHOT_FRAMES
    from gldt_core.sim.spec import SceneSpec

    long = SceneRenderer(SceneSpec(seed=4, frames=10**9, size=(160, 120), targets=2))
    short = SceneRenderer(SceneSpec(seed=4, frames=SHOT_FRAMES, size=(160, 120), targets=2))
    for frame in (0, 1, SHOT_FRAMES - 1):
        image, rows = long.render_with_truth(frame)
        image_short, rows_short = short.render_with_truth(frame)
        assert np.array_equal(image, image_short) and np.array_equal(rows, rows_short)
    image, rows = long.render_with_truth(SHOT_FRAMES)  # the second shot: new paths, same sky
    assert image.shape == (120, 160, 3)
    assert np.all(rows[:, 0] == SHOT_FRAMES + 1)
    again, rows_again = SceneRenderer(long.spec).render_with_truth(SHOT_FRAMES)
    assert np.array_equal(image, again) and np.array_equal(rows, rows_again)
