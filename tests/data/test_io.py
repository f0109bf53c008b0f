import json
import os
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

import hocnet.data.io as io_module
from hocnet.data.binary import paper_scene
from hocnet.data.io import load_cube, load_tracks_json, save_cube, save_tracks_json


def only_file(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


class TestLoadCube:
    @pytest.mark.parametrize("suffix", [".npy", ".npz"])
    @pytest.mark.parametrize("dtype", [torch.bool, torch.float32, torch.float64, torch.uint8])
    @pytest.mark.parametrize("shape", [(3, 4, 5), (2, 3, 4, 5)])
    def test_roundtrip(self, tmp_path, suffix, dtype, shape):
        cube = (torch.rand(shape, generator=torch.Generator().manual_seed(0)) > 0.5).to(dtype)
        save_cube(tmp_path / f"c{suffix}", cube)
        loaded = load_cube(tmp_path / f"c{suffix}")
        assert loaded.dtype == dtype and torch.equal(loaded, cube)
        assert only_file(tmp_path) == [f"c{suffix}"]

    def test_binary_flag(self, tmp_path):
        np.save(tmp_path / "c.npy", np.eye(4, dtype=np.float32)[None].repeat(2, 0))
        cube = load_cube(tmp_path / "c.npy", binary=True)
        assert cube.dtype == torch.bool and cube.shape == (2, 4, 4) and int(cube.sum()) == 8

    def test_str_path_and_scene(self, tmp_path):
        scene = paper_scene("table3", 0.05, seed=0)
        save_cube(str(tmp_path / "s.npz"), scene.cube)
        assert torch.equal(load_cube(str(tmp_path / "s.npz"), binary=True), scene.cube)

    def test_npz_keys(self, tmp_path):
        np.savez(tmp_path / "m.npz", a=np.zeros((2, 3, 3)), b=np.ones((2, 3, 3)))
        assert load_cube(tmp_path / "m.npz", key="b").sum() == 18
        with pytest.raises(ValueError, match=r"`key`: expected one of 'a', 'b' .*got None"):
            load_cube(tmp_path / "m.npz")
        with pytest.raises(ValueError, match=r"`key`: expected one of 'a', 'b' .*got 'c'"):
            load_cube(tmp_path / "m.npz", key="c")

    def test_npz_single_array_any_name(self, tmp_path):
        np.savez(tmp_path / "s.npz", frames=np.zeros((2, 3, 3), dtype=bool))
        assert load_cube(tmp_path / "s.npz").shape == (2, 3, 3)

    def test_big_endian_and_uint16(self, tmp_path):
        np.save(tmp_path / "be.npy", np.arange(12, dtype=">f4").reshape(1, 3, 4))
        np.save(tmp_path / "u.npy", np.arange(12, dtype=np.uint16).reshape(1, 3, 4))
        assert load_cube(tmp_path / "be.npy")[0, 2, 3].item() == 11.0
        u = load_cube(tmp_path / "u.npy")
        assert u.dtype == torch.int64 and u[0, 2, 3].item() == 11

    def test_missing_file(self, tmp_path):
        with pytest.raises(FileNotFoundError, match=r"`path`: no such file .*nope\.npy"):
            load_cube(tmp_path / "nope.npy")

    def test_wrong_extension(self, tmp_path):
        (tmp_path / "c.txt").write_text("1 2 3")
        with pytest.raises(ValueError, match=r"`path`: expected a \.npy or \.npz file.*c\.txt"):
            load_cube(tmp_path / "c.txt")

    def test_wrong_path_type(self):
        with pytest.raises(TypeError, match="`path`"):
            load_cube(3)

    @pytest.mark.parametrize(
        ("name", "kind"), [("bad.npy", "a valid .npy file"), ("bad.npz", "a valid .npz archive")]
    )
    def test_unreadable(self, tmp_path, name, kind):
        (tmp_path / name).write_bytes(b"definitely not numpy" * 5)
        with pytest.raises(ValueError, match=rf"`path`: '.*{name}' is not {kind}") as info:
            load_cube(tmp_path / name)
        assert "pickle" not in str(info.value)

    def test_text_file_named_npy_never_suggests_unsafe_loading(self, tmp_path):
        # issue 9: numpy's own message advises allow_pickle=True for a text file
        (tmp_path / "t.npy").write_text("1 2 3\n4 5 6\n")
        with pytest.raises(ValueError, match=r"t\.npy' is not a valid \.npy file") as info:
            load_cube(tmp_path / "t.npy")
        assert "pickle" not in str(info.value).lower()

    def test_empty_file(self, tmp_path):
        (tmp_path / "e.npy").write_bytes(b"")
        with pytest.raises(ValueError, match=r"`path`: '.*e\.npy' is not a valid \.npy file"):
            load_cube(tmp_path / "e.npy")

    def test_object_array(self, tmp_path):
        np.save(tmp_path / "o.npy", np.array([None, 1], dtype=object), allow_pickle=True)
        with pytest.raises(ValueError, match=r"`path`: could not read .*o\.npy") as info:
            load_cube(tmp_path / "o.npy")
        assert "allow_pickle" not in str(info.value)
        assert "never loads" in str(info.value)

    @pytest.mark.parametrize("dtype", [np.uint16, np.uint32, np.uint64])
    def test_wide_unsigned_converted_exactly(self, tmp_path, dtype):
        top = np.iinfo(dtype).max if dtype != np.uint64 else 2**63 - 1
        array = np.zeros((2, 3, 3), dtype=dtype)
        array[1, 2, 2] = top
        np.save(tmp_path / "u.npy", array)
        cube = load_cube(tmp_path / "u.npy")
        assert cube.dtype == torch.int64
        assert int(cube[1, 2, 2]) == int(top) and int(cube.min()) == 0

    def test_uint64_above_int64_refused(self, tmp_path):
        # issue 9: values above 2**63 loaded as negative numbers and the DPA ran on them
        array = np.zeros((2, 3, 3), dtype=np.uint64)
        array[0, 0, 0] = 2**63 + 5
        np.save(tmp_path / "u.npy", array)
        with pytest.raises(
            ValueError, match=r"u\.npy' holds uint64 values up to 9223372036854775813"
        ):
            load_cube(tmp_path / "u.npy")

    def test_format_mismatch(self, tmp_path):
        np.save(tmp_path / "a.npy", np.zeros((2, 3, 3)))
        os.rename(tmp_path / "a.npy", tmp_path / "a.npz")
        with pytest.raises(ValueError, match=r"`path`: expected a \.npz archive"):
            load_cube(tmp_path / "a.npz")
        np.savez(tmp_path / "b.npz", x=np.zeros((2, 3, 3)))
        os.rename(tmp_path / "b.npz", tmp_path / "b.npy")
        with pytest.raises(ValueError, match=r"`path`: expected a \.npy array"):
            load_cube(tmp_path / "b.npy")

    def test_key_with_npy(self, tmp_path):
        np.save(tmp_path / "a.npy", np.zeros((2, 3, 3)))
        with pytest.raises(ValueError, match="`key`: expected None"):
            load_cube(tmp_path / "a.npy", key="a")
        with pytest.raises(TypeError, match="`key`"):
            load_cube(tmp_path / "a.npy", key=1)

    @pytest.mark.parametrize("shape", [(3, 4), (1, 2, 3, 4, 5), (0, 3, 3)])
    def test_wrong_rank(self, tmp_path, shape):
        np.save(tmp_path / "r.npy", np.zeros(shape))
        with pytest.raises(ValueError, match=r"`path`: '.*r\.npy' does not hold a valid cube"):
            load_cube(tmp_path / "r.npy")

    def test_non_binary(self, tmp_path):
        np.save(tmp_path / "n.npy", np.full((2, 3, 3), 2.0))
        assert load_cube(tmp_path / "n.npy").max() == 2.0
        with pytest.raises(ValueError, match=r"n\.npy.*binary values"):
            load_cube(tmp_path / "n.npy", binary=True)

    def test_nan(self, tmp_path):
        np.save(tmp_path / "nan.npy", np.full((2, 3, 3), np.nan))
        with pytest.raises(ValueError, match=r"nan\.npy.*finite"):
            load_cube(tmp_path / "nan.npy")

    def test_string_array(self, tmp_path):
        np.save(tmp_path / "s.npy", np.full((2, 3, 3), "a"))
        with pytest.raises(ValueError, match=r"`path`: .*s\.npy"):
            load_cube(tmp_path / "s.npy")


class TestSaveCube:
    def test_accepts_numpy(self, tmp_path):
        save_cube(tmp_path / "c.npy", np.ones((2, 3, 3), dtype=bool))
        assert np.load(tmp_path / "c.npy").dtype == bool

    def test_npz_key(self, tmp_path):
        save_cube(tmp_path / "c.npz", torch.zeros(2, 3, 3), key="frames")
        with np.load(tmp_path / "c.npz") as data:
            assert data.files == ["frames"]

    def test_bfloat16_saved_as_float32(self, tmp_path):
        save_cube(tmp_path / "c.npy", torch.ones(2, 3, 3, dtype=torch.bfloat16))
        assert load_cube(tmp_path / "c.npy").dtype == torch.float32

    def test_overwrites(self, tmp_path):
        save_cube(tmp_path / "c.npy", torch.zeros(2, 3, 3))
        save_cube(tmp_path / "c.npy", torch.ones(2, 3, 3))
        assert load_cube(tmp_path / "c.npy").sum() == 18
        assert only_file(tmp_path) == ["c.npy"]

    @pytest.mark.parametrize(
        ("kwargs", "error", "match"),
        [
            ({"cube": torch.zeros(3, 3)}, ValueError, "`cube`: expected shape"),
            ({"cube": torch.full((2, 3, 3), float("nan"))}, ValueError, "`cube`"),
            ({"cube": "abc"}, TypeError, "`cube`"),
            ({"name": "c.txt"}, ValueError, "`path`: expected a .npy or .npz"),
            ({"name": "missing/c.npy"}, FileNotFoundError, "`path`: directory"),
            ({"key": ""}, TypeError, "`key`"),
        ],
    )
    def test_exceptions(self, tmp_path, kwargs, error, match):
        cube = kwargs.pop("cube", torch.zeros(2, 3, 3))
        name = kwargs.pop("name", "c.npz")
        with pytest.raises(error, match=match):
            save_cube(tmp_path / name, cube, **kwargs)
        assert list(tmp_path.rglob("*")) == []

    def test_directory_target(self, tmp_path):
        (tmp_path / "d.npy").mkdir()
        with pytest.raises(ValueError, match="`path`: expected a file name"):
            save_cube(tmp_path / "d.npy", torch.zeros(2, 3, 3))

    def test_failing_write_leaves_nothing(self, tmp_path, monkeypatch):
        def broken_save(handle, array, allow_pickle=False):
            handle.write(b"\x93NUMPY partial")
            raise OSError("disk full")

        monkeypatch.setattr(io_module.np, "save", broken_save)
        with pytest.raises(OSError, match="disk full"):
            save_cube(tmp_path / "c.npy", torch.zeros(2, 3, 3))
        assert only_file(tmp_path) == []

    @pytest.mark.parametrize(
        "error",
        [
            OSError(28, "No space left on device"),
            OSError("163840 requested and 159616 written"),  # numpy's short write
        ],
    )
    def test_disk_full_names_the_path(self, tmp_path, monkeypatch, error):
        # issue 9: a full disk said "163840 requested and 159616 written" and nothing else
        def full_disk(handle, array, allow_pickle=False):
            handle.write(b"\x93NUMPY partial")
            raise error

        monkeypatch.setattr(io_module.np, "save", full_disk)
        target = tmp_path / "c.npy"
        with pytest.raises(OSError, match=r"no space left on device") as info:
            save_cube(target, torch.zeros(2, 3, 3))
        assert f"'{target}'" in str(info.value)
        assert ".tmp" not in str(info.value)
        assert info.value.errno == 28
        assert only_file(tmp_path) == []

    def test_failing_write_keeps_old_file(self, tmp_path, monkeypatch):
        save_cube(tmp_path / "c.npy", torch.ones(2, 3, 3))

        def broken_replace(src, dst):
            raise OSError("rename failed")

        monkeypatch.setattr(io_module.os, "replace", broken_replace)
        with pytest.raises(OSError, match="rename failed"):
            save_cube(tmp_path / "c.npy", torch.zeros(2, 3, 3))
        monkeypatch.undo()
        assert only_file(tmp_path) == ["c.npy"]
        assert load_cube(tmp_path / "c.npy").sum() == 18


def make_tracks():
    return [
        SimpleNamespace(id=1, score=3.2, points=torch.tensor([[0, 5, 7], [1, 5, 8], [2, 6, 9]])),
        SimpleNamespace(id=4, score=-0.5, points=torch.zeros(0, 3, dtype=torch.int64)),
    ]


class TestTracksJson:
    def test_roundtrip(self, tmp_path):
        target = tmp_path / "t.json"
        save_tracks_json(target, make_tracks(), method="hoc", v=4, delta=0.785)
        tracks, meta = load_tracks_json(target, return_meta=True)
        assert meta == {"method": "hoc", "v": 4, "delta": 0.785}
        assert [t["id"] for t in tracks] == [1, 4]
        assert [t["score"] for t in tracks] == [3.2, -0.5]
        assert tracks[0]["points"].dtype == torch.int64
        assert torch.equal(tracks[0]["points"], make_tracks()[0].points)
        assert tracks[1]["points"].shape == (0, 3)
        assert load_tracks_json(target)[0]["id"] == 1
        assert only_file(tmp_path) == ["t.json"]

    def test_format(self, tmp_path):
        save_tracks_json(tmp_path / "t.json", make_tracks()[:1], n=2)
        document = json.loads((tmp_path / "t.json").read_text())
        assert document == {
            "meta": {"n": 2},
            "tracks": [{"id": 1, "score": 3.2, "points": [[0, 5, 7], [1, 5, 8], [2, 6, 9]]}],
        }

    def test_empty_and_resave_dicts(self, tmp_path):
        save_tracks_json(tmp_path / "e.json", [])
        assert load_tracks_json(tmp_path / "e.json", return_meta=True) == ([], {})
        save_tracks_json(tmp_path / "a.json", make_tracks())
        save_tracks_json(tmp_path / "b.json", load_tracks_json(tmp_path / "a.json"))
        assert (tmp_path / "a.json").read_text() == (tmp_path / "b.json").read_text()

    def test_meta_conversion(self, tmp_path):
        save_tracks_json(
            tmp_path / "t.json",
            [],
            shape=torch.Size([2, 3]),
            cube=Path("x.npy"),
            density=np.float32(0.5),
            ids=torch.tensor([1, 2]),
        )
        _, meta = load_tracks_json(tmp_path / "t.json", return_meta=True)
        assert meta == {"shape": [2, 3], "cube": "x.npy", "density": 0.5, "ids": [1, 2]}

    def test_numpy_and_float_points(self, tmp_path):
        tracks = [{"id": 1, "score": 1, "points": np.array([[0.0, 1.0, 2.0]])}]
        save_tracks_json(tmp_path / "t.json", tracks)
        assert load_tracks_json(tmp_path / "t.json")[0]["points"].tolist() == [[0, 1, 2]]

    @pytest.mark.parametrize(
        ("tracks", "meta", "error", "match"),
        [
            ("abc", {}, TypeError, "`tracks`"),
            ([SimpleNamespace(id=1, score=1.0)], {}, TypeError, r"`tracks\[0\]`"),
            ([{"id": 1, "points": [[0, 0, 0]]}], {}, TypeError, r"`tracks\[0\]`"),
            ([{"id": 1.5, "score": 1, "points": []}], {}, TypeError, r"`tracks\[0\]\.id`"),
            (
                [{"id": 1, "score": float("nan"), "points": []}],
                {},
                ValueError,
                r"`tracks\[0\]\.score`",
            ),
            ([{"id": 1, "score": 1, "points": [[0, 1]]}], {}, ValueError, r"`tracks\[0\]\.points`"),
            (
                [{"id": 1, "score": 1, "points": [[0, 1, 2.5]]}],
                {},
                ValueError,
                r"`tracks\[0\]\.points`: expected integer",
            ),
            (
                [{"id": 1, "score": 1, "points": torch.ones(1, 3, dtype=torch.bool)}],
                {},
                TypeError,
                r"`tracks\[0\]\.points`",
            ),
            ([], {"bad": object()}, TypeError, r"`meta\['bad'\]`"),
            ([], {"bad": float("nan")}, ValueError, r"`meta\['bad'\]`"),
        ],
    )
    def test_save_exceptions(self, tmp_path, tracks, meta, error, match):
        with pytest.raises(error, match=match):
            save_tracks_json(tmp_path / "t.json", tracks, **meta)
        assert only_file(tmp_path) == []

    def test_save_missing_directory(self, tmp_path):
        with pytest.raises(FileNotFoundError, match="`path`: directory"):
            save_tracks_json(tmp_path / "no" / "t.json", [])

    def test_failing_write_leaves_nothing(self, tmp_path, monkeypatch):
        def broken_replace(src, dst):
            raise OSError("rename failed")

        monkeypatch.setattr(io_module.os, "replace", broken_replace)
        with pytest.raises(OSError, match="rename failed"):
            save_tracks_json(tmp_path / "t.json", make_tracks())
        assert only_file(tmp_path) == []

    def test_load_missing(self, tmp_path):
        with pytest.raises(FileNotFoundError, match=r"`path`: no such file .*x\.json"):
            load_tracks_json(tmp_path / "x.json")

    @pytest.mark.parametrize(
        ("text", "match"),
        [
            ("{not json", "is not valid JSON"),
            ("[1, 2]", '"tracks" list'),
            ('{"tracks": [], "meta": 3}', '"meta" to be an object'),
            ('{"tracks": [{"id": 1}]}', "track 0 to be an object"),
            ('{"tracks": [{"id": "a", "score": 1, "points": []}]}', 'integer "id"'),
            ('{"tracks": [{"id": 1, "score": "x", "points": []}]}', 'number "score"'),
            ('{"tracks": [{"id": 1, "score": 1, "points": [[1, 2]]}]}', '"points" of track 0'),
            ('{"tracks": [{"id": 1, "score": 1, "points": [[1, 2, 0.5]]}]}', '"points"'),
            ('{"tracks": [{"id": 1, "score": 1, "points": [[1, 2, 1e30]]}]}', '"points"'),
            (
                '{"tracks": [{"id": 1, "score": 1, "points": [[1, 2, 99999999999999999999]]}]}',
                "int64",
            ),
        ],
    )
    def test_load_exceptions(self, tmp_path, text, match):
        (tmp_path / "t.json").write_text(text)
        with pytest.raises(ValueError, match=match):
            load_tracks_json(tmp_path / "t.json")
        with pytest.raises(ValueError, match=r"`path`: .*t\.json"):
            load_tracks_json(tmp_path / "t.json")
