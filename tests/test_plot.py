import matplotlib.pyplot as plt
import numpy as np
import pytest
import torch
from matplotlib.figure import Figure

from hocnet.data.binary import TargetSpec, simulate_binary
from hocnet.data.io import load_tracks_json, save_tracks_json
from hocnet.hoc import detect
from hocnet.plot import plot_before_after, plot_cube_3d, plot_map, plot_tracks

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def assert_png(path):
    assert path.is_file() and path.stat().st_size > 1000
    assert path.read_bytes()[:8] == PNG_MAGIC


def legend_texts(fig):
    return [t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()]


@pytest.fixture(scope="module")
def scene():
    targets = [
        TargetSpec((2, 3), (2, 1)),
        TargetSpec((20, 4), (-1, 2)),
        TargetSpec((3, 20), (2, 0)),
    ]
    return simulate_binary((8, 24, 24), targets, clutter_density=0.02, seed=0)


@pytest.fixture(scope="module")
def result(scene):
    return detect(scene.cube)


@pytest.fixture(autouse=True)
def no_pyplot_figures():
    """The plot functions never register figures with pyplot (no leaks, no windows)."""
    before = plt.get_fignums()
    yield
    assert plt.get_fignums() == before


class TestPlotCube3d:
    def test_labels(self, tmp_path, scene):
        fig = plot_cube_3d(scene.cube, labels=scene.labels, path=tmp_path / "c.png")
        assert isinstance(fig, Figure)
        assert_png(tmp_path / "c.png")
        ax = fig.axes[0]
        assert (ax.get_xlabel(), ax.get_ylabel(), ax.get_zlabel()) == (
            "x (pixels)",
            "y (pixels)",
            "scan",
        )
        texts = legend_texts(fig)
        assert texts[0] == f"clutter ({int(scene.n_clutter_points)})"
        assert [t.split(" (")[0] for t in texts[1:]] == ["target 1", "target 2", "target 3"]
        assert ax.get_ylim()[0] > ax.get_ylim()[1]  # y down, as in the image

    def test_no_labels_colours_by_scan(self, scene):
        fig = plot_cube_3d(scene.cube[None], title="mine")  # a batch of one is accepted
        assert fig.axes[0].get_title() == "mine"
        assert fig.axes[-1].get_ylabel() == "scan"  # the colour bar

    def test_empty_cube(self, tmp_path):
        fig = plot_cube_3d(torch.zeros(3, 5, 6, dtype=torch.bool), path=tmp_path / "e.png")
        assert "0 points" in fig.axes[0].get_title()
        assert_png(tmp_path / "e.png")

    def test_into_given_axes(self):
        fig = Figure()
        ax = fig.add_subplot(projection="3d")
        assert plot_cube_3d(torch.ones(2, 3, 3), ax=ax) is fig

    @pytest.mark.parametrize(
        ("kwargs", "error", "match"),
        [
            ({"cube": torch.zeros(2, 3, 4, 4)}, ValueError, "`cube`: expected one scene"),
            ({"cube": torch.zeros(4, 4)}, ValueError, r"`cube`: expected shape \(T, H, W\)"),
            ({"cube": torch.full((2, 3, 3), 0.5)}, ValueError, "`cube`: expected binary"),
            (
                {"labels": torch.zeros(2, 3, 4, dtype=torch.long)},
                ValueError,
                "`labels`: expected shape",
            ),
            ({"labels": torch.zeros(2, 3, 3)}, TypeError, "`labels`: expected an integer tensor"),
            ({"ax": "axes"}, TypeError, "`ax`"),
        ],
    )
    def test_errors(self, kwargs, error, match):
        args = {"cube": torch.zeros(2, 3, 3, dtype=torch.bool), **kwargs}
        cube = args.pop("cube")
        with pytest.raises(error, match=match):
            plot_cube_3d(cube, **args)

    def test_2d_axes_rejected(self):
        ax = Figure().add_subplot()
        with pytest.raises(ValueError, match="`ax`: expected a 3-D Axes"):
            plot_cube_3d(torch.zeros(2, 3, 3), ax=ax)


class TestPlotBeforeAfter:
    def test_result(self, tmp_path, scene, result):
        fig = plot_before_after(
            scene.cube,
            result,
            labels=scene.labels,
            true_tracks=scene.tracks,
            title="demo",
            path=tmp_path / "ba.png",
        )
        assert_png(tmp_path / "ba.png")
        left, right = fig.axes[:2]
        assert left.get_title().startswith(f"Input: {int(scene.cube.sum())} points in 8 scans")
        assert right.get_title().startswith(f"Detection: {len(result.tracks)} tracks")
        for ax in (left, right):
            assert (ax.get_xlabel(), ax.get_ylabel()) == ("x (pixels)", "y (pixels)")
        texts = legend_texts(fig)
        assert "true track" in texts
        listed = [t for t in texts if t.startswith("track ")]
        assert len(listed) == min(len(result.tracks), 12)
        for text in listed:  # each listed track is one of the result's, with its length
            tid = int(text.split(":")[0].split()[1])
            track = next(tr for tr in result.tracks if tr.id == tid)
            assert text.startswith(f"track {tid}: {len(track)} pts")
        if len(result.tracks) > 12:
            assert (
                texts[-1]
                == f"+ {len(result.tracks) - 12} more tracks ({len(result.tracks)} in all)"
            )
        assert fig._suptitle.get_text() == "demo"

    def test_false_track_marked(self, scene):
        fake = detect(scene.cube)
        fake.tracks[0].points = torch.tensor([[0, 20, 20], [1, 21, 21], [2, 22, 22]])
        fig = plot_before_after(scene.cube, fake, true_tracks=scene.tracks)
        assert any(
            t.startswith(f"track {fake.tracks[0].id}:") and t.endswith("(false)")
            for t in legend_texts(fig)
        )

    def test_cleaned_cube(self, scene, result):
        fig = plot_before_after(scene.cube, result.cleaned)
        kept = int(result.cleaned.sum())
        assert (
            fig.axes[1].get_title() == f"Detection: {kept} of {int(scene.cube.sum())} points kept"
        )

    def test_empty(self, tmp_path):
        empty = torch.zeros(5, 8, 9, dtype=torch.bool)
        fig = plot_before_after(empty, detect(empty), path=tmp_path / "e.png")
        assert fig.axes[1].get_title().startswith("Detection: 0 tracks")
        assert_png(tmp_path / "e.png")

    def test_shape_mismatch(self, scene):
        with pytest.raises(
            ValueError, match="`result_or_cleaned`: expected a cleaned cube of shape"
        ):
            plot_before_after(scene.cube, torch.zeros(8, 5, 5, dtype=torch.bool))

    def test_missing_directory(self, tmp_path, scene):
        with pytest.raises(FileNotFoundError, match="`path`"):
            plot_before_after(scene.cube, scene.cube, path=tmp_path / "no" / "x.png")


class TestPlotTracks:
    def test_forms_of_tracks(self, tmp_path, scene, result):
        save_tracks_json(tmp_path / "t.json", result.tracks)
        loaded = load_tracks_json(tmp_path / "t.json")
        arrays = [t.points.numpy() for t in result.tracks]
        for i, tracks in enumerate([result.tracks, loaded, arrays]):
            path = tmp_path / "t.png" if i == 0 else None
            fig = plot_tracks(tracks, scene.cube.shape, true_tracks=scene.tracks, path=path)
            ax = fig.axes[0]
            assert ax.get_title() == f"{len(result.tracks)} tracks"
            assert ax.get_xlim() == (-0.5, 23.5) and ax.get_ylim() == (23.5, -0.5)
        assert_png(tmp_path / "t.png")
        texts = legend_texts(plot_tracks(loaded, (8, 24, 24)))
        assert texts[0].startswith("track ") and "score" in texts[0]

    def test_no_tracks(self, tmp_path):
        fig = plot_tracks([], (5, 10, 10), path=tmp_path / "n.png")
        assert fig.axes[0].get_title() == "0 tracks"
        assert_png(tmp_path / "n.png")

    def test_many_tracks_listed_up_to_the_cap(self):
        tracks = [np.array([[0, k, 0], [1, k, 1]]) for k in range(20)]
        texts = legend_texts(plot_tracks(tracks, (2, 20, 5)))
        assert len(texts) == 13 and texts[-1] == "+ 8 more tracks (20 in all)"

    def test_false_tracks_listed_first_when_many(self):
        truth = [np.array([[0, 0, 0], [1, 0, 1]])]
        tracks = [np.array([[0, 0, 0], [1, 0, 1]])] * 14 + [np.array([[0, 9, 3], [1, 9, 4]])]
        texts = legend_texts(plot_tracks(tracks, (2, 20, 5), true_tracks=truth))
        assert texts[1] == "track 15: 2 pts (false)"  # after "true track"

    def test_into_given_axes(self):
        fig = Figure()
        ax = fig.add_subplot()
        assert plot_tracks([[[0, 1, 1], [1, 2, 2]]], (2, 4, 4), ax=ax, title="t") is fig
        assert ax.get_title() == "t"

    @pytest.mark.parametrize(
        ("tracks", "shape", "error", "match"),
        [
            ([np.zeros((3, 2))], (2, 4, 4), ValueError, r"`tracks\[0\]`: expected \(N, 3\)"),
            ([[[0, 1, float("nan")]]], (2, 4, 4), ValueError, r"`tracks\[0\]`: expected finite"),
            (
                [{"id": 1}],
                (2, 4, 4),
                TypeError,
                r"`tracks\[0\]`: expected a mapping with a 'points'",
            ),
            (torch.zeros(2, 3), (2, 4, 4), TypeError, "`tracks`: expected a list of tracks"),
            ([], (4, 4), TypeError, "`shape`"),
            ([], (2, 0, 4), ValueError, r"`shape\[1\]`"),
        ],
    )
    def test_errors(self, tracks, shape, error, match):
        with pytest.raises(error, match=match):
            plot_tracks(tracks, shape)


class TestPlotMap:
    @pytest.mark.parametrize(
        "image",
        [
            torch.rand(6, 9),
            np.arange(12).reshape(3, 4),
            torch.zeros(4, 4, dtype=torch.bool),
            torch.tensor([[1.0, float("nan")], [0.0, 2.0]]),  # NaN shown blank
        ],
    )
    def test_images(self, tmp_path, image):
        fig = plot_map(image, title="map", path=tmp_path / "m.png")
        assert_png(tmp_path / "m.png")
        assert len(fig.axes) == 2 and fig.axes[0].get_title() == "map"
        assert fig.axes[0].get_xlabel() == "x (pixels)"

    def test_no_colorbar(self):
        assert len(plot_map(torch.zeros(3, 3), colorbar=False).axes) == 1

    @pytest.mark.parametrize(
        ("image", "error", "match"),
        [
            (torch.zeros(2, 3, 3), ValueError, r"`image`: expected shape \(H, W\)"),
            (torch.zeros(0, 3), ValueError, r"`image`: expected shape \(H, W\)"),
            (torch.zeros(2, 2, dtype=torch.complex64), TypeError, "`image`: expected a real"),
            ("abc", TypeError, "`image`"),
        ],
    )
    def test_errors(self, image, error, match):
        with pytest.raises(error, match=match):
            plot_map(image)


class TestPlotDPA:
    def test_figure_and_png(self, tmp_path):
        from hocnet.plot import plot_dpa

        frames = torch.randn(4, 10, 12, generator=torch.Generator().manual_seed(0))
        track = torch.tensor([[1, 1], [2, 2], [3, 3], [4, 4]])
        path = tmp_path / "dpa.png"
        fig = plot_dpa(frames, frames.cumsum(0), [track], truth=track.float(), path=path)
        assert type(fig).__name__ == "Figure" and path.stat().st_size > 1000

    def test_shape_mismatch(self):
        from hocnet.plot import plot_dpa

        with pytest.raises(ValueError, match="`asf`"):
            plot_dpa(torch.zeros(3, 4, 4), torch.zeros(2, 4, 4))


# --------------------------------------------------------------------------------------------
# issue 9: pictures at real sizes, scores in the DPA legend, 3-D legend counts
# --------------------------------------------------------------------------------------------


def scatter_offsets(ax):
    """Number of markers drawn by the scatter plots of ``ax``."""
    from matplotlib.collections import PathCollection

    return sum(len(c.get_offsets()) for c in ax.collections if isinstance(c, PathCollection))


class TestRealSizes:
    def test_large_input_is_a_density_image(self, tmp_path):
        # issue 9: on 512 x 640 x 100 the left panel was one solid block of 328k points
        g = torch.Generator().manual_seed(0)
        cube = torch.rand(100, 512, 640, generator=g) < 0.01
        assert int(cube.sum()) > 300_000
        empty = argparse_result(cube)
        fig = plot_before_after(cube, empty, path=tmp_path / "big.png")
        left = fig.axes[0]
        assert scatter_offsets(left) <= 20_000
        images = left.get_images()
        assert len(images) == 1
        counts = images[0].get_array()
        assert counts.shape == (512, 640) and int(counts.sum()) == int(cube.sum())
        assert "density" in left.get_title() and f"{int(cube.sum())} points" in left.get_title()
        assert_png(tmp_path / "big.png")

    def test_small_input_keeps_one_marker_per_point(self, scene, result):
        fig = plot_before_after(scene.cube, result)
        assert scatter_offsets(fig.axes[0]) == int(scene.cube.sum())
        assert fig.axes[0].get_images() == []


def argparse_result(cube):
    from types import SimpleNamespace

    none = torch.zeros_like(cube)
    return SimpleNamespace(support=none, cleaned=none, tracks=[])


class TestDPALegend:
    def test_every_track_listed_with_its_score_and_drawn(self):
        from hocnet.plot import plot_dpa

        frames = torch.zeros(5, 16, 16)
        tracks = [
            torch.tensor([[1, 1], [2, 2], [3, 3], [4, 4], [5, 5]]),
            torch.tensor([[9, 9]] * 5),  # stays in one pixel: must still be visible
            torch.tensor([[12, 3], [12, 4], [13, 5], [13, 6], [14, 7]]),
        ]
        fig = plot_dpa(frames, frames, tracks, scores=[7.5, 0.25, 3.0])
        texts = [t.get_text() for t in fig.legends[0].get_texts()]
        assert texts == ["track 1: score 7.5", "track 2: score 0.25", "track 3: score 3"]
        ax = fig.axes[0]
        drawn = {line.get_label(): line for line in ax.get_lines()}
        for text, tr in zip(texts, tracks):
            line = drawn[text]
            assert line.get_marker() not in (None, "None", "", " ")  # a point shows up
            np.testing.assert_array_equal(line.get_xdata(), tr[:, 0].numpy())
            x0, x1 = sorted(ax.get_xlim())
            assert ((line.get_xdata() >= x0) & (line.get_xdata() <= x1)).all()

    def test_scores_must_match_tracks(self):
        from hocnet.plot import plot_dpa

        with pytest.raises(ValueError, match="`scores`"):
            plot_dpa(torch.zeros(3, 4, 4), torch.zeros(3, 4, 4), [torch.zeros(3, 2)], scores=[])


class TestCube3dCounts:
    def test_legend_counts_agree_with_the_demo_table(self):
        # issue 9: demo_3d.png's legend counts disagreed with the printed table (shared points)
        from hocnet.data.binary import paper_scene

        scene = paper_scene("table3", 0.014, seed=0)
        fig = plot_cube_3d(
            scene.cube,
            labels=scene.labels,
            true_tracks=scene.tracks,
            track_labels=scene.track_labels,
        )
        texts = legend_texts(fig)
        track_points = [{tuple(p) for p in tr.tolist()} for tr in scene.tracks]
        on_any = set().union(*track_points)
        clutter = int(scene.cube.sum()) - len(on_any)
        assert clutter == int(scene.n_clutter_points)
        expected = [f"clutter ({clutter})"] + [
            f"target {label} ({len(points)})"
            for label, points in zip(scene.track_labels, track_points)
        ]
        assert texts == expected
        # the demo table's "points" column counts the same sets
        assert any(a & b for i, a in enumerate(track_points) for b in track_points[i + 1 :])

    def test_demo_passes_the_true_tracks(self, tmp_path, monkeypatch):
        import hocnet.plot
        from hocnet.cli import main

        seen = {}
        real = hocnet.plot.plot_cube_3d

        def spy(*args, **kwargs):
            seen.update(kwargs)
            return real(*args, **kwargs)

        monkeypatch.setattr(hocnet.plot, "plot_cube_3d", spy)
        assert main(["demo", "--no-dpa", "--out", str(tmp_path / "d"), "--quiet"]) == 0
        assert seen["true_tracks"] is not None and seen["track_labels"] is not None
