import os

import numpy as np
import pytest
import torch
from PIL import Image

from hocnet.data.frames import load_frames, natural_key


def save(path, array, mode=None):
    Image.fromarray(array, mode=mode).save(path) if mode else Image.fromarray(array).save(path)


@pytest.fixture
def clip(tmp_path):
    """Three 8-bit frames named so that natural and lexicographic order differ."""
    folder = tmp_path / "clip"
    folder.mkdir()
    arrays = {}
    for i in (1, 2, 10):
        a = (np.arange(20, dtype=np.uint8).reshape(4, 5) + 10 * i).astype(np.uint8)
        save(folder / f"frame{i}.png", a)
        arrays[i] = a
    return folder, arrays


class TestLoadFrames:
    def test_folder_natural_order(self, clip):
        folder, arrays = clip
        got = load_frames(folder)
        assert got.dtype == torch.float32 and got.shape == (3, 4, 5)
        want = np.stack([arrays[1], arrays[2], arrays[10]]).astype(np.float32)
        np.testing.assert_array_equal(got.numpy(), want)

    def test_glob_and_single_file(self, clip):
        folder, arrays = clip
        got = load_frames(str(folder / "frame1*.png"))  # frame1, frame10
        np.testing.assert_array_equal(got.numpy(), np.stack([arrays[1], arrays[10]]))
        one = load_frames(folder / "frame2.png", dtype=torch.uint8)
        assert one.dtype == torch.uint8 and one.shape == (1, 4, 5)

    def test_formats_and_16_bit(self, tmp_path):
        a16 = (np.arange(12, dtype=np.uint16).reshape(3, 4) * 5000).astype(np.uint16)
        for i, ext in enumerate((".png", ".tif")):
            Image.fromarray(a16).save(tmp_path / f"f{i}{ext}")
        got = load_frames(tmp_path)
        assert float(got.max()) == 55000.0  # not rescaled
        np.testing.assert_array_equal(got[1].numpy(), a16.astype(np.float32))
        bmp = tmp_path / "b"
        bmp.mkdir()
        save(bmp / "x.bmp", np.full((3, 3), 7, np.uint8))
        assert load_frames(bmp).tolist() == [[[7.0] * 3] * 3]

    def test_colour_converted_with_warning(self, tmp_path):
        rgb = np.zeros((2, 3, 3), np.uint8)
        rgb[..., 0] = 100  # pure red -> L = 0.299 * 100
        save(tmp_path / "c0.png", rgb)
        with pytest.warns(UserWarning, match="colour frame.*converted to grey"):
            got = load_frames(tmp_path)
        assert got.shape == (1, 2, 3) and float(got[0, 0, 0]) == pytest.approx(30, abs=1)

    def test_npy_npz(self, tmp_path):
        cube = np.random.default_rng(0).integers(0, 255, (3, 4, 5)).astype(np.uint8)
        np.save(tmp_path / "c.npy", cube)
        np.savez(tmp_path / "c.npz", frames=cube, truth_xy=np.zeros((3, 2)))
        np.savez(tmp_path / "one.npz", cube)
        np.testing.assert_array_equal(load_frames(tmp_path / "c.npy").numpy(), cube)
        np.testing.assert_array_equal(load_frames(tmp_path / "c.npz", key="frames").numpy(), cube)
        np.testing.assert_array_equal(load_frames(tmp_path / "one.npz").numpy(), cube)
        with pytest.raises(ValueError, match=r"`key`: expected the name of the array"):
            load_frames(tmp_path / "c.npz")
        with pytest.raises(ValueError, match=r"`key`: expected one of \['frames', 'truth_xy'\]"):
            load_frames(tmp_path / "c.npz", key="cube")
        np.save(tmp_path / "flat.npy", cube[0])
        with pytest.raises(ValueError, match=r"expected frames of shape \(T, H, W\)"):
            load_frames(tmp_path / "flat.npy")

    def test_inputs_untouched(self, clip):
        folder, _ = clip
        before = {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in folder.iterdir()}
        load_frames(folder)
        after = {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in folder.iterdir()}
        assert before == after

    def test_errors(self, tmp_path, clip):
        folder, _ = clip
        empty = tmp_path / "empty"
        empty.mkdir()
        with pytest.raises(ValueError, match=r"empty .*empty"):
            load_frames(empty)
        (folder / "notes.txt").write_text("hi")
        with pytest.raises(ValueError, match=r"got the file notes.txt"):
            load_frames(folder)
        os.remove(folder / "notes.txt")
        (folder / "frame99.png").write_bytes(b"not a png")
        with pytest.raises(ValueError, match=r"frame99\.png"):
            load_frames(folder)
        os.remove(folder / "frame99.png")
        save(folder / "frame50.png", np.zeros((5, 5), np.uint8))
        with pytest.raises(ValueError, match=r"one size.*frame50\.png"):
            load_frames(folder)
        with pytest.raises(FileNotFoundError, match="`source`"):
            load_frames(tmp_path / "missing")
        with pytest.raises(ValueError, match="pattern matching"):
            load_frames(str(tmp_path / "nothing*.png"))
        with pytest.raises(TypeError, match="`source`"):
            load_frames(3)

    def test_hidden_files_ignored(self, clip):
        folder, _ = clip
        (folder / ".DS_Store").write_bytes(b"\0")
        assert load_frames(folder).shape == (3, 4, 5)


def test_natural_key_vs_lexicographic():
    names = ["f_10.png", "f_9.png", "f_100.png"]
    assert sorted(names, key=natural_key) == ["f_9.png", "f_10.png", "f_100.png"]
    padded = ["f_010.png", "f_009.png", "f_100.png"]
    assert sorted(padded, key=natural_key) == sorted(padded)


class TestFrameFilesAndExports:
    def test_frame_files_order(self, clip):
        from hocnet.data.frames import frame_files

        folder, _ = clip
        assert [p.name for p in frame_files(folder)] == ["frame1.png", "frame2.png", "frame10.png"]
        assert [p.name for p in frame_files(str(folder / "frame1*"))] == [
            "frame1.png",
            "frame10.png",
        ]
        assert frame_files(folder / "frame2.png") == [folder / "frame2.png"]
        with pytest.raises(FileNotFoundError, match="`source`"):
            frame_files(folder / "absent")

    def test_reexported(self):
        import hocnet.data
        import hocnet.data.io

        assert hocnet.data.io.load_frames is load_frames
        assert hocnet.data.load_frames is load_frames
