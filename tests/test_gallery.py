"""The gallery's parts (ocpipe.gallery): which episodes it picks, what its frames say, how its contact sheets are laid
out, the videos it writes, and that a state set on the policy's env draws what the evaluation's cameras saw; then
the tiny run's galleries (tests/conftest.py builds two), end to end."""

import numpy as np
import polars as pl
import pytest
import torch
from conftest import GALLERIES, REPO

from ocpipe import paths
from ocpipe.evaluation import replay
from ocpipe.evaluation.taxonomy import CLASSES
from ocpipe.gallery import build, overlay, render, selection, sheet, slots, video
from ocpipe.sim import envs
from ocpipe.study import targets
from ocpipe.util import video_page


def classified(counts: dict[str, int], policies=("goal2d", "goal2d@1"), trivial: int = 0) -> dict[str, pl.DataFrame]:
    """failures.parquet of each policy: ``counts`` episodes of each class, spread over the policies, seeds unique."""
    rows = {p: [] for p in policies}
    seed = 10_000
    for cls, n in counts.items():
        for i in range(n):
            rows[policies[i % len(policies)]].append({"run": 0, "seed": seed, "trivial": False, "class": cls})
            seed += 1
    for i in range(trivial):
        rows[policies[0]].append({"run": 0, "seed": seed + i, "trivial": True, "class": "Success"})
    return {p: pl.DataFrame(r) for p, r in rows.items()}


def test_picks_are_the_same_every_time_n_per_class_present_and_all_of_a_smaller_class():
    episodes = selection.candidates(classified({"Success": 9, "Drop": 5, "Near Miss": 1}, trivial=3))
    picks = selection.pick(episodes, 2, seed=0, row="goal2d")
    assert picks.equals(selection.pick(episodes, 2, seed=0, row="goal2d"))  # exact: the same draw again
    assert picks.group_by("class").len().sort("class").rows() == [("Drop", 2), ("Near Miss", 1), ("Success", 2)]
    assert picks["class"].to_list() == ["Success", "Success", "Drop", "Drop", "Near Miss"]  # the taxonomy's order
    assert picks["n"].to_list() == [0, 1, 0, 1, 0]
    assert len(picks.unique(["policy", "run", "seed"])) == len(picks)  # without replacement
    assert not set(picks["seed"]) & set(range(10_015, 10_018))  # trivial successes are never shown
    assert len(selection.pick(episodes, 20, seed=0, row="goal2d")) == 15  # every episode where a class has fewer


def test_the_seed_and_the_row_choose_the_picks_and_a_class_does_not_depend_on_the_others():
    episodes = selection.candidates(classified({"Success": 30, "Drop": 30}))
    picks = {s: set(selection.pick(episodes, 3, seed=s, row="goal2d")["seed"]) for s in range(4)}
    assert len({frozenset(p) for p in picks.values()}) > 1
    assert set(selection.pick(episodes, 3, seed=0, row="goal3d")["seed"]) != picks[0]
    alone = selection.pick(episodes.filter(pl.col("class") == "Drop"), 3, seed=0, row="goal2d")
    both = selection.pick(episodes, 3, seed=0, row="goal2d").filter(pl.col("class") == "Drop")
    assert alone.equals(both)  # exact: the same draw for the class, whatever else is present


def test_picking_refuses_unknown_classes_and_a_zero_count():
    episodes = selection.candidates(classified({"Success": 2}))
    with pytest.raises(ValueError, match="at least 1"):
        selection.pick(episodes, 0, seed=0)
    with pytest.raises(ValueError, match="'Crash'"):
        selection.pick(episodes.with_columns(pl.lit("Crash").alias("class")), 1, seed=0)
    with pytest.raises(ValueError, match="policy goal2d: no column class"):
        selection.candidates({"goal2d": pl.DataFrame({"run": [0], "seed": [1], "trivial": [False]})})


def test_the_gallery_covers_the_main_jobs_and_stackcubes_rows(default_config):
    rows = selection.rows(default_config)
    assert rows["goal2d"] == {"table5_1": "2D-Spatial-Proj", "table5_2": "2D-Spatial-Proj"}
    assert rows["stack_aligned"] == {"table5_10": "Aligned (base + side, 2D goal)",
                                     "table5_11": "Aligned (base + side, 2D goal)"}
    assert set(rows) == {"pure_visual", "goal2d", "goal3d", "state_control", "stack_native", "stack_aligned"}
    assert set(selection.rows(default_config, ("main",))) == {"pure_visual", "goal2d", "goal3d", "state_control"}
    assert set(selection.rows(default_config, ("stackcube",))) == {"stack_native", "stack_aligned"}
    with pytest.raises(ValueError, match=r"no scope \['ablations'\]"):
        selection.rows(default_config, ("ablations",))
    assert selection.row_title(rows["goal2d"]) == "Tables 5.1, 5.2: 2D-Spatial-Proj"
    assert selection.row_title(rows["stack_native"]) == "Table 5.10: Native (base + hand, no goal)"
    assert [selection.class_of_slug(selection.slug(c)) for c in CLASSES] == list(CLASSES)
    assert selection.video_label("near_miss", "3", "10244") == {"item": "Near Miss: policy 3, seed 10244"}


def test_a_group_target_lists_a_rows_gallery_once_every_part_of_it_is_there(tmp_path):
    assert selection.outputs(["goal2d"]) == ["results/gallery/goal2d/videos", "results/gallery/goal2d/sheets",
                                             "results/gallery/goal2d/episodes.csv"]
    assert selection.built(["goal2d", "goal3d"], tmp_path) == []
    (tmp_path / "results/gallery/goal2d/videos").mkdir(parents=True)
    (tmp_path / "results/gallery/goal2d/sheets").mkdir()
    assert selection.built(["goal2d", "goal3d"], tmp_path) == []  # no manifest yet: a job that did not finish
    (tmp_path / "results/gallery/goal2d/episodes.csv").write_text("row\n")
    assert selection.built(["goal2d", "goal3d"], tmp_path) == selection.outputs(["goal2d"])


def one_episode(grasped, tcp_goal, obj_goal, gripper) -> pl.DataFrame:
    """Goal at the origin; TCP and object on the x axis at the given distances."""
    n = len(grasped)
    return pl.DataFrame({"seed": [7] * n, "step": list(range(n)), "is_grasped": grasped,
                         "tcp_pos": [[d, 0.0, 0.0] for d in tcp_goal], "obj_pos": [[d, 0.0, 0.0] for d in obj_goal],
                         "goal_pos": [[0.0, 0.0, 0.0]] * n, "action": [[0.0] * 7 + [g] for g in gripper]})


def test_a_near_miss_names_its_closest_approach_and_a_drop_where_the_grasp_was_lost():
    steps = one_episode([False, True, True, False, False], [0.3, 0.2, 0.05, 0.08, 0.25], [0.3, 0.2, 0.12, 0.4, 0.5],
                        [1.0, -1.0, -1.0, 1.0, 1.0])
    near = overlay.episode_facts(steps, "Near Miss")
    assert (near.deciding_step, near.deciding_distance) == (2, 0.05)  # exact: a distance along one axis, copied
    drop = overlay.episode_facts(steps, "Drop")
    assert (drop.deciding_step, drop.deciding_distance) == (3, 0.4)  # exact: as above
    assert overlay.episode_facts(steps, "No Grasp").deciding_step is None
    lines = overlay.frame_lines("Tables 5.1, 5.2: 2D", "Drop", "goal2d@1", 7, 2, drop, 0.10)
    assert lines[1] == "Drop | policy goal2d@1 | seed 7"
    assert lines[2] == "grasp lost at step 3: object 0.400 m from the goal"
    assert lines[3] == "step 2/5 | gripper commanded closed | grasped yes"  # action 1 closed it; observation 2 holds
    assert lines[4] == "TCP-goal 0.050 m, object-goal 0.120 m"
    assert "Near Miss: < 0.1 m" in overlay.frame_lines("r", "Near Miss", "p", 7, 0, near, 0.10)[2]
    assert overlay.frame_lines("r", "Drop", "p", 7, 0, drop, 0.1)[3] == "step 0/5 | gripper commanded - | grasped no"
    last = overlay.frame_lines("r", "Drop", "p", 7, 5, drop, 0.1)
    assert last[3].endswith("grasped not observed") and "not observed" in last[4]
    # a class decided by no single step has no such line
    assert len(overlay.frame_lines("r", "No Grasp", "p", 7, 0, drop, 0.1)) == 4
    with pytest.raises(ValueError, match="frame 6 of an episode of 5 steps"):
        overlay.frame_lines("r", "Drop", "p", 7, 6, drop, 0.1)
    with pytest.raises(ValueError, match="classed Drop but its record never lets go"):
        overlay.episode_facts(one_episode([False, True], [0.1, 0.1], [0.1, 0.1], [1.0, -1.0]), "Drop")


def test_captions_wrap_to_the_frame_and_keep_their_line_count():
    lines = overlay.wrap(["word " * 60, "short"], 200)
    assert len(lines) == overlay.CAPTION_LINES and lines[-1].endswith("...")
    from PIL import Image, ImageDraw

    draw = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    assert all(draw.textlength(line, font=overlay._font()) <= 200 for line in lines[:-1])
    assert overlay.wrap(["a b", "", "c"], 200) == ["a b", "", "c"]


def test_the_longest_real_caption_keeps_its_deciding_line_at_the_gallerys_width(default_config):
    """The widest row title and class line, the Near Miss line and the last frame's, at the default resolution and
    at a smaller one, where the lines after the class wrap and the caption is cut."""
    title = max((selection.row_title(t) for t in selection.rows(default_config).values()), key=len)
    near = overlay.episode_facts(one_episode([False] * 200, [0.5] * 199 + [0.123], [0.5] * 200, [1.0] * 200),
                                 "Near Miss")
    lines = overlay.frame_lines(title, "Near Miss", "stack_aligned@4", 10945, 200, near, 0.05)
    for size in (default_config["gallery"]["resolution"], 200):
        wrapped = overlay.wrap(lines, size + size // 2 - 2 * overlay.MARGIN)
        assert "closest TCP-goal 0.123 m at step 199 (Near Miss: < 0.05 m)" in wrapped, (size, wrapped)


def test_a_frame_puts_the_viewer_left_the_policys_views_right_and_the_caption_below():
    viewer = np.random.default_rng(0).integers(0, 255, (64, 64, 3), dtype=np.uint8)
    views = [np.full((16, 16, 3), 200, np.uint8), np.full((16, 16, 3), 50, np.uint8)]
    frame = overlay.compose(viewer, views, ["a caption"])
    height = 64 + overlay.CAPTION_LINES * overlay.LINE_HEIGHT + 2 * overlay.MARGIN + overlay.CONTROLS_BAND
    assert frame.shape == (height + height % 2, 96, 3) and frame.shape[0] % 2 == 0
    np.testing.assert_array_equal(frame[:64, :64], viewer)  # exact: pasted as it is
    # exact: each view enlarged 16 -> 32 px by nearest neighbour, one above the other
    np.testing.assert_array_equal(frame[:32, 64:96], 200)
    np.testing.assert_array_equal(frame[32:64, 64:96], 50)  # exact: as above
    assert (frame[64:] != overlay.BACKGROUND).any()  # the caption is drawn
    assert (frame[-overlay.CONTROLS_BAND:] == overlay.BACKGROUND).all()  # and the player's controls cover none of it
    empty = overlay.compose(viewer, [], ["a caption"], no_views="no camera")
    assert empty.shape == frame.shape and (empty[:64, 64:] == overlay.PANEL).all(-1).mean() > 0.8


def test_a_contact_sheet_spreads_its_steps_and_lays_out_rows_by_columns():
    assert sheet.sheet_steps(150, 6) == [0, 30, 60, 90, 120, 150]
    assert sheet.sheet_steps(3, 6) == [0, 1, 2, 3]  # an episode shorter than the sheet: each frame once
    with pytest.raises(ValueError, match="at least 2"):
        sheet.sheet_steps(10, 1)
    # the step that decided the class replaces the nearest inner frame (ties: the earlier), never the first or last
    assert sheet.sheet_steps(150, 6, deciding=47) == [0, 30, 47, 90, 120, 150]
    assert sheet.sheet_steps(150, 6, deciding=45) == [0, 45, 60, 90, 120, 150]
    assert sheet.sheet_steps(150, 6, deciding=149) == [0, 30, 60, 90, 149, 150]
    assert sheet.sheet_steps(150, 6, deciding=60) == [0, 30, 60, 90, 120, 150]
    assert sheet.sheet_steps(10, 2, deciding=4) == [0, 4, 10]
    with pytest.raises(ValueError, match="deciding step 151 is outside the episode's steps 0..150"):
        sheet.sheet_steps(150, 6, deciding=151)
    grid = sheet.layout(3, 6, 40)
    assert grid.width == sheet.LABEL_WIDTH + sheet.GAP + 6 * (40 + sheet.GAP)
    assert grid.height == sheet.TITLE_HEIGHT + sheet.HEADER_HEIGHT + 3 * (40 + sheet.GAP)
    boxes = sorted(grid.origins.values())
    assert len(set(boxes)) == 18 and all(x + 40 <= grid.width and y + 40 <= grid.height for x, y in boxes)
    assert grid.origins[1, 2][0] - grid.origins[1, 1][0] == 44 and grid.origins[2, 0][1] - grid.origins[1, 0][1] == 44
    panels = [[np.full((20, 20, 3), 10 * (r + 1) + c, np.uint8) for c in range(6)] for r in range(3)]
    image = np.asarray(sheet.contact_sheet(["title", "sub"], ["viewer", "base", "masks"], [0, 1, 2, 3, 4, 5],
                                           panels, 40))
    assert image.shape == (grid.height, grid.width, 3)
    x, y = grid.origins[2, 4]
    assert (image[y:y + 40, x:x + 40] == 34).all()  # exact: row 2, column 4's panel, enlarged by nearest neighbour
    with pytest.raises(ValueError, match="3 rows x 6 steps"):
        sheet.contact_sheet(["t"], ["a", "b", "c"], [0, 1, 2, 3, 4, 5], panels[:2], 40)


def test_episodes_are_drawn_from_their_recorded_states_and_a_run_without_them_is_named():
    def steps(seeds, with_state):
        rows = [{"seed": s, "step": k, "action": [0.1 * k] * 8, **({"state": [float(s + k)] * 3} if with_state else {})}
                for s in seeds for k in range(3)]
        return pl.DataFrame(rows)
    episodes = pl.DataFrame({"seed": [7, 5], "success": [True, False]})
    records = render.recorded_episodes("PickCube-v1", episodes, steps([7, 5], True), {5}, "run.episodes.parquet")
    assert list(records) == [5] and records[5].success is False
    assert records[5].states[:, 0].tolist() == [5.0, 6.0, 7.0]  # exact: small integers as float32
    with pytest.raises(ValueError, match=r"run.episodes.parquet: seeds \[9\] are not episodes of this run"):
        render.recorded_episodes("PickCube-v1", episodes, steps([7, 5], True), {5, 9}, "run.episodes.parquet")
    with pytest.raises(ValueError, match="old.episodes.parquet: its steps file has no 'state' column"):
        render.recorded_episodes("PickCube-v1", episodes, steps([7, 5], False), {5}, "old.episodes.parquet")


def test_a_video_draws_every_stride_th_state_and_the_last():
    assert render.drawn_frames(10, 3) == [0, 3, 6, 9, 10]
    assert render.drawn_frames(9, 3, extra=[4]) == [0, 3, 4, 6, 9]
    with pytest.raises(ValueError, match="frame_stride"):
        render.drawn_frames(9, 0)


def decoded(path):
    """(frames, (width, height)) of a written video, read back by its decoder."""
    if path.suffix == ".gif":
        from PIL import Image

        with Image.open(path) as gif:
            return gif.n_frames, gif.size
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    return sum(1 for _ in reader), tuple(meta["size"])


@pytest.mark.parametrize("use_ffmpeg", [True, False])
def test_videos_decode_to_their_frames_as_mp4_or_as_gif_without_ffmpeg(tmp_path, use_ffmpeg):
    frames = [np.full((34, 48, 3), 7 * i, np.uint8) for i in range(9)]
    written = video.write_video(frames, tmp_path / "episode.mp4", fps=10, use_ffmpeg=use_ffmpeg)
    assert written.suffix == (".mp4" if use_ffmpeg else ".gif")
    assert decoded(written) == (9, (48, 34))
    assert not list(tmp_path.glob(".tmp-*"))
    if use_ffmpeg:  # one encoder thread, bit-exact flags: the same bytes again
        again = video.write_video(frames, tmp_path / "again.mp4", fps=10)
        assert again.read_bytes() == written.read_bytes()  # one-cpu: x264 twice on this machine
    with pytest.raises(ValueError, match="even sides"):
        video.write_video([np.zeros((33, 48, 3), np.uint8)], tmp_path / "odd.mp4", fps=10)


class FakeSlots:
    """A slot encoder of two slots on a 4 x 4 grid over a 16 px crop at (8, 4): slot 1 claims the right half."""

    windows = np.array([[8, 4, 16]])

    def encode(self, rgb):
        masks = torch.zeros(1, 1, 2, 4, 4)
        masks[..., 0, :, :2] = 1.0
        masks[..., 1, :, 2:] = 1.0
        return None, masks


def test_slot_maps_colour_the_encoders_crop_by_the_slot_that_claims_each_cell():
    image = np.zeros((32, 32, 3), np.uint8)
    out = slots.slot_map(FakeSlots(), image)
    assert out.shape == (16, 16, 3)
    # exact: on a black image the cell is its slot's colour times ALPHA, rounded
    np.testing.assert_array_equal(out[:, :8], np.round(slots.ALPHA * slots.PALETTE[0]).astype(np.uint8)[None, None]
                                  .repeat(16, 0).repeat(8, 1))
    np.testing.assert_array_equal(out[:, 8:], np.round(slots.ALPHA * slots.PALETTE[1]).astype(np.uint8)[None, None]
                                  .repeat(16, 0).repeat(8, 1))  # exact: as above


def test_a_recorded_state_set_on_the_policys_env_draws_what_its_cameras_saw():
    """The gallery draws the policy's views from recorded states (no physics): the link poses then come from the
    joint positions rather than the integrator, which may move an outline by a last float bit."""
    from ocpipe.config import validate as C

    config = C.load(REPO / "config" / "config.yaml")
    stepped = envs.make_env("PickCube-v1", config, "dual", 64, obs_mode="rgb")
    mirror = envs.make_env("PickCube-v1", config, "dual", 64, obs_mode="rgb")
    viewer = envs.make_viewer_env("PickCube-v1", config, 64)
    try:
        stepped.reset(seed=10_001)
        mirror.reset(seed=10_001)
        home = stepped.unwrapped.agent.robot.get_qpos()[0].numpy()
        for t in range(12):  # the arm swings and the gripper closes: every link moves
            target = np.r_[home[:7] + 0.05 * t * np.array([1, -1, 1, -1, 1, -1, 1]), -1.0].astype(np.float32)
            obs, *_ = stepped.step(torch.as_tensor(target[None]))
            state = torch.from_numpy(replay.env_state(stepped)[None])
            mirror.unwrapped.set_state(state)
            drawn = mirror.unwrapped.get_obs()
            for uid in ("base_camera", "side_camera"):
                a = obs["sensor_data"][uid]["rgb"][0].numpy().astype(int)
                b = drawn["sensor_data"][uid]["rgb"][0].numpy().astype(int)
                # derived: a last-bit change of a link pose moves an outline by under a pixel: at most a pixel's
                # shade changes, on at most one image row's worth of pixels
                assert (a != b).any(-1).sum() <= 64
            viewer.unwrapped.set_state(state)
            assert viewer.render().shape == (1, 64, 64, 3)
    finally:
        for env in (stepped, mirror, viewer):
            env.close()


def test_a_page_embeds_its_video_by_kind_and_a_too_long_video_is_encoded_again_smaller(tmp_path, monkeypatch):
    gif = video.write_gif([np.zeros((8, 8, 3), np.uint8)] * 2, tmp_path / "e.gif", fps=5)
    video_page.write(gif, tmp_path / "e.html", "row: Drop", ("policy goal2d@1, seed 7",))
    text = (tmp_path / "e.html").read_text()
    assert '<img alt="episode" src="data:image/gif;base64,' in text and "<p>policy goal2d@1, seed 7</p>" in text
    with pytest.raises(ValueError, match="not '.webm'"):
        video_page.page(b"", "t", suffix=".webm")
    rng = np.random.default_rng(0)  # noise: the encoder cannot shrink it much, so each quality step is visible
    frames = [rng.integers(0, 255, (64, 64, 3), dtype=np.uint8) for _ in range(8)]
    sizes = {crf: video.write_video(frames, tmp_path / f"crf{crf}.mp4", fps=10, crf=crf).stat().st_size
             for crf in build.CRF_STEPS}
    assert sizes[build.CRF_STEPS[0]] > sizes[build.CRF_STEPS[1]] > sizes[build.CRF_STEPS[2]]
    # a page limit between the first and second quality's pages: the second is written, and its page fits
    limit = len(video_page.page(b"x" * sizes[build.CRF_STEPS[1]], "t").encode()) + 64
    monkeypatch.setattr(video_page, "PAGE_LIMIT", limit)
    written = build.write_video_and_page(frames, tmp_path / "episode.mp4", 10, "t", ())
    assert written.stat().st_size == sizes[build.CRF_STEPS[1]]  # exact: the same encoder, the same bytes
    assert (tmp_path / "episode.html").stat().st_size <= limit
    monkeypatch.setattr(video_page, "PAGE_LIMIT", 100)
    with pytest.raises(ValueError, match="episode.mp4: its report page"):
        build.write_video_and_page(frames, tmp_path / "episode.mp4", 10, "t", ())


@pytest.mark.parametrize("gallery", GALLERIES)
def test_the_tiny_runs_gallery_shows_each_class_of_its_row_in_videos_pages_and_one_sheet(tiny_run, gallery):
    from ocpipe.config import validate as C

    config = C.load(REPO / "config" / "config.yaml", tiny_run / "tiny.yaml")
    folder = tiny_run / gallery.rsplit("/", 1)[0]
    exp = folder.name
    picked = pl.read_csv(folder / "episodes.csv")
    classified = pl.concat(
        pl.read_parquet(tiny_run / paths.FAILURES.format(exp=pid)).with_columns(policy=pl.lit(pid))
        for pid in targets.policies(config, exp)).filter(~pl.col("trivial"))
    per_class = classified.group_by("class").len()
    wanted = {c: min(n, config["gallery"]["episodes_per_class"]) for c, n in per_class.iter_rows()}
    assert dict(picked.group_by("class").len().iter_rows()) == wanted  # every class present, at most N each
    # each pick is an episode of that class, and its steps and success are its record's
    assert picked.join(classified, on=["policy", "run", "seed", "class"], how="anti").is_empty()
    assert picked["success"].to_list() == [c == "Success" for c in picked["class"]]
    stride = config["gallery"]["frame_stride"]
    for row in picked.iter_rows(named=True):
        assert 1 <= row["steps"] <= config["evaluation"]["episode_cap"]["PickCube-v1"]
        clip = folder / "videos" / row["video"]
        assert decoded(clip)[0] == build.frames_in_video(row["steps"], stride)
        page = clip.with_suffix(".html").read_text()
        assert "base64," in page and row["class"] in page and f"seed {row['seed']}" in page
    sheets = {f.name for f in (folder / "sheets").glob("*.png")}
    assert sheets == {f"{selection.slug(c)}.png" for c in wanted}  # one per class
    assert set(picked.filter(pl.col("sheet").fill_null("") != "")["sheet"]) == sheets
    assert not list(folder.rglob(".tmp-*"))
