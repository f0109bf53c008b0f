"""Tests of hocnet.learn.train (`hocnet train` through LightningCLI) and its configs."""

from __future__ import annotations

import warnings

import pytest
import yaml

L = pytest.importorskip("lightning")
pytest.importorskip("jsonargparse")

from hocnet.hoc.layers import MHOCImage  # noqa: E402
from hocnet.learn import load_model  # noqa: E402
from hocnet.learn.train import (  # noqa: E402
    CONFIG_DIR,
    SYSTEMS,
    ConfigError,
    build_cli,
    config_path,
    expand_argv,
    parse_error_message,
    train_main,
)

#: Tiny data for every system (overrides of the committed configs).
TINY = {
    "dpa": ["--data.n_train", "2", "--data.n_val", "2", "--data.n_test", "2",
            "--data.shape", "5", "16", "16", "--data.speed", "0.1", "1.0",
            "--data.batch_size", "2"],
    "hoc": ["--data.n_train", "2", "--data.n_val", "2", "--data.n_test", "2",
            "--data.shape", "6", "16", "16", "--data.speed", "0.1", "1.0",
            "--data.batch_size", "2", "--model.order", "1", "--model.v", "1"],
}  # fmt: skip


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


class TestExpandArgv:
    def test_short_forms_and_lists(self):
        argv = ["--max-epochs", "3", "--out", "o", "--seed", "4", "--no-progress",
                "--model.learnable", "b", "g", "--data.snr_db", "12",
                "--config", "c.yaml"]  # fmt: skip
        assert expand_argv(argv) == [
            "--trainer.max_epochs", "3", "--trainer.default_root_dir", "o",
            "--seed_everything", "4", "--trainer.enable_progress_bar", "false",
            "--model.learnable", "[b,g]", "--data.snr_db", "12", "--config", "c.yaml",
        ]  # fmt: skip
        assert expand_argv(["--data.speed=[0.1,1]", "--data.seed", "-1"]) == [
            "--data.speed=[0.1,1]",
            "--data.seed",
            "-1",
        ]


class TestConfigs:
    @pytest.mark.parametrize("system", sorted(SYSTEMS))
    def test_committed_config_fast_dev_run(self, system, tmp_path, capsys):
        path = config_path(system)
        assert path.parent == CONFIG_DIR and path.is_file()
        argv = [system, "--config", str(path), "--trainer.fast_dev_run", "true",
                "--out", str(tmp_path), "--no-progress", *TINY[system]]  # fmt: skip
        assert train_main(argv) == 0
        out = capsys.readouterr().out
        assert "test/loss = " in out and "test/pd = " in out
        assert "checkpoint: none (fast_dev_run saves no checkpoint)" in out

    @pytest.mark.parametrize("system", sorted(SYSTEMS))
    def test_config_values_reach_the_classes(self, system, tmp_path):
        path = config_path(system)
        config = yaml.safe_load(path.read_text())
        cli = build_cli(system, ["--config", str(path), "--out", str(tmp_path)])
        for key, value in config["model"].items():
            got = cli.model.hparams[key]
            if key == "learnable" and cli.model.hparams.get("matrices") == "full":
                continue
            assert (list(got) if isinstance(got, tuple) else got) == value, key
        for key, value in config["data"].items():
            got = cli.datamodule.hparams[key]
            assert (list(got) if isinstance(got, tuple) else got) == value, key
        assert cli.trainer.max_epochs == config["trainer"]["max_epochs"]

    def test_print_config_round_trips(self, tmp_path, capsys):
        with pytest.raises(SystemExit) as exit_:
            train_main(["hoc", "--model.lr", "0.3", "--data.shape", "6", "20", "20",
                        "--print_config"])  # fmt: skip
        assert exit_.value.code == 0
        printed = yaml.safe_load(capsys.readouterr().out)
        assert printed["model"]["lr"] == 0.3 and printed["data"]["shape"] == [6, 20, 20]
        assert set(printed) >= {"model", "data", "trainer", "seed_everything"}
        config = tmp_path / "c.yaml"
        config.write_text(yaml.safe_dump(printed))
        cli = build_cli("hoc", ["--config", str(config)])
        assert cli.model.hparams["lr"] == 0.3 and cli.datamodule.shape == (6, 20, 20)


class TestCLI:
    @pytest.mark.parametrize("system", sorted(SYSTEMS))
    def test_help_lists_every_option(self, system, capsys):
        with pytest.raises(SystemExit):
            train_main([system, "--help"])
        text = capsys.readouterr().out
        model_cls, data_cls = SYSTEMS[system]
        import inspect

        for prefix, cls in (("model", model_cls), ("data", data_cls), ("trainer", L.Trainer)):
            for name in inspect.signature(cls.__init__).parameters:
                if name != "self":
                    assert f"--{prefix}.{name}" in text, f"--{prefix}.{name}"
        assert "--config" in text and "--print_config" in text
        for short in ("--out DIR", "--max-epochs N", "--seed N", "--no-progress, -q"):
            assert short in text, short

    def test_usage_without_system(self, capsys):
        assert train_main(["--help"]) == 0
        assert train_main(["-h"]) == 0
        out = capsys.readouterr().out
        assert "dpa" in out and "hoc" in out and "hocnet train dpa --help" in out
        with pytest.raises(ConfigError, match="expected a system dpa or hoc first, got none"):
            train_main([])
        with pytest.raises(ConfigError, match="got 'svm'"):
            train_main(["svm"])

    def test_bad_values_name_the_argument(self):
        with pytest.raises(ConfigError, match=r"^--model.lr: expected a number in"):
            build_cli("dpa", ["--model.lr", "-1"])
        with pytest.raises(ConfigError, match=r"^--model.matrices: expected one of"):
            build_cli("dpa", ["--model.matrices", "diagonal"])
        with pytest.raises(ConfigError, match=r"^--data.speed: "):
            build_cli("hoc", ["--data.speed", "0.1", "3.0"])
        with pytest.raises(ConfigError, match=r"^--trainer.max_epochs must be"):
            build_cli("dpa", ["--trainer.max_epochs", "-3"])

    def test_defaults_are_documented(self):
        cli = build_cli("dpa", [])
        assert cli.trainer.max_epochs == 10
        assert cli.model.hparams["matrices"] == "paper"

    def test_hoc_end_to_end_checkpoint(self, tmp_path, capsys):
        argv = ["hoc", "--max-epochs", "1", "--out", str(tmp_path), "--no-progress",
                "--trainer.limit_train_batches", "1", "--trainer.limit_val_batches", "1",
                *TINY["hoc"]]  # fmt: skip
        assert train_main(argv) == 0
        out = capsys.readouterr().out
        assert "test/clutter_rejection" in out and "test/auroc" in out
        ckpt = out.split("checkpoint: ")[-1].strip()
        assert isinstance(load_model(ckpt), MHOCImage)
        assert list(tmp_path.rglob("metrics.csv"))
        (saved,) = tmp_path.rglob("config.yaml")  # the resolved config beside the logs
        assert yaml.safe_load(saved.read_text())["model"]["order"] == 1


def _files(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


class TestErrors:
    """Parse and value errors: one line naming the flag, before the seed or any file."""

    @pytest.mark.parametrize(
        ("argv", "message"),
        [
            (["--config", "nope.yaml"], "--config: file 'nope.yaml' does not exist"),
            (["--model.lr", "nan"], "--model.lr: expected a finite number, got nan"),
            (["--model.lr", "inf"], "--model.lr: expected a finite number, got inf"),
            (["--model.lr", "abc"], "--model.lr: expected a number, got abc"),
            (["--data.shape", "[8,32]"], "--data.shape: expected 3 values, got [8, 32]"),
            (["--data.shape", "8", "32"], "--data.shape: expected 3 values, got [8, 32]"),
            (["--data.n_train", "x"], "--data.n_train: expected an integer, got x"),
            (["--seed", "q"], "--seed: expected true or false or an integer, got q"),
            (["--model.lr"], "--model.lr: expected one argument"),
            (["--bogus", "1"], "unrecognized arguments: --bogus 1 (see 'hocnet train dpa --help')"),
            (
                ["--max-epochs", "0"],
                "--max-epochs: expected at least 1 (or -1 for no limit), got 0",
            ),
            (["--trainer.max_epochs", "0"], "--trainer.max_epochs: expected at least 1"),
            (["--trainer.max_steps", "0"], "--trainer.max_steps: expected at least 1"),
            (["--trainer.limit_train_batches", "0"], "--trainer.limit_train_batches: expected > 0"),
            (["--data.n_train", "0"], "--data.n_train: expected an integer >= 1"),
            (["--data.n_test", "0"], "--data.n_test: expected an integer >= 1"),
            (["--model.tau_end", "0"], "--model.tau_end: expected a number in (0, inf), got 0"),
            (["--model.window", "4"], "--model.window: expected an odd integer, got 4"),
        ],
    )
    def test_one_line_naming_the_flag(self, argv, message, tmp_path, monkeypatch):
        import logging

        monkeypatch.chdir(tmp_path)
        seen = []
        handler = logging.Handler()
        handler.emit = lambda record: seen.append(record.getMessage())
        seed_log = logging.getLogger("lightning.fabric.utilities.seed")
        seed_log.addHandler(handler)
        try:
            with pytest.raises(ConfigError) as err:
                build_cli("dpa", argv)
        finally:
            seed_log.removeHandler(handler)
        text = str(err.value)
        assert text.startswith(message) and "\n" not in text, text
        assert not [m for m in seen if m.startswith("Seed set")]
        assert _files(tmp_path) == []

    def test_seed_is_logged_once_valid(self, tmp_path):
        import logging

        seen = []
        handler = logging.Handler()
        handler.emit = lambda record: seen.append(record.getMessage())
        seed_log = logging.getLogger("lightning.fabric.utilities.seed")
        seed_log.addHandler(handler)
        try:
            build_cli("dpa", ["--seed", "3", "--out", str(tmp_path)])
        finally:
            seed_log.removeHandler(handler)
        assert seen == ["Seed set to 3"]

    def test_parse_error_messages(self):
        union = (
            'Parser key "trainer.max_epochs":\n  Does not validate against any of the Union '
            "subtypes\n  Subtypes: [<class 'int'>, <class 'NoneType'>]\n  Errors:\n"
            "    - Expected <class 'int'>\n    - Expected <class 'NoneType'>\n"
            "  Given value type: <class 'str'>\n  Given value: a"
        )
        assert (
            parse_error_message(union) == "--trainer.max_epochs: expected an integer or null, got a"
        )
        short = {"seed_everything": "--seed"}
        message = "Parser key \"seed_everything\":\n  Expected a <class 'int'>. Got value: x"
        assert parse_error_message(message, short) == "--seed: expected an integer, got x"
        assert parse_error_message("argument --model.lr: expected one argument") == (
            "--model.lr: expected one argument"
        )

    def test_out_is_a_file(self, tmp_path, monkeypatch):
        monkeypatch.chdir(tmp_path)
        (tmp_path / "notes.txt").write_text("mine")
        with pytest.raises(ConfigError, match=r"^--out: 'notes.txt' is a file, expected a folder$"):
            build_cli("dpa", ["--out", "notes.txt"])
        with pytest.raises(
            ConfigError, match=r"^--trainer.default_root_dir: 'notes.txt' is a file"
        ):
            build_cli("dpa", ["--trainer.default_root_dir", "notes.txt"])
        with pytest.raises(ConfigError, match=r"^--out: 'notes.txt' is a file, cannot create"):
            build_cli("dpa", ["--out", "notes.txt/run"])
        assert _files(tmp_path) == ["notes.txt"]

    def test_failed_run_removes_only_its_files(self, tmp_path, monkeypatch):
        old = tmp_path / "logs" / "version_0"
        old.mkdir(parents=True)
        (old / "config.yaml").write_text("earlier run")
        model_cls, _ = SYSTEMS["dpa"]

        def broken(self, batch, batch_idx):
            raise RuntimeError("broken step")

        monkeypatch.setattr(model_cls, "training_step", broken)
        argv = ["dpa", "--max-epochs", "1", "--out", str(tmp_path), "-q", *TINY["dpa"]]
        with pytest.raises(RuntimeError, match="broken step"):
            train_main(argv)
        assert _files(tmp_path) == ["logs", "logs/version_0", "logs/version_0/config.yaml"]
        fresh = tmp_path / "new" / "run"  # a new --out folder (and its parent) is removed
        with pytest.raises(RuntimeError, match="broken step"):
            train_main(["dpa", "--max-epochs", "1", "--out", str(fresh), "-q", *TINY["dpa"]])
        assert not (tmp_path / "new").exists()


def test_datamodule_without_training_scenes_names_n_train():
    _, data_cls = SYSTEMS["dpa"]
    data = data_cls(n_train=0, n_val=1, n_test=1, shape=(4, 16, 16))
    assert len(data.test_dataloader().dataset) == 1  # test-only modules stay valid
    with pytest.raises(ValueError, match=r"^`n_train`: expected an integer >= 1"):
        data.train_dataloader()


class TestProgressAndCheckpoints:
    @pytest.mark.parametrize(("tty", "argv", "bar"), [
        (False, [], False), (True, [], True), (True, ["-q"], False),
        (True, ["--trainer.enable_progress_bar", "null"], True),
        (True, ["--no-progress"], False), (False, ["--trainer.enable_progress_bar", "true"], True),
    ])  # fmt: skip
    def test_progress_bar_only_on_a_terminal(self, tty, argv, bar, monkeypatch, tmp_path):
        import sys

        monkeypatch.setattr(sys.stderr, "isatty", lambda: tty, raising=False)
        cli = build_cli("dpa", [*argv, "--out", str(tmp_path)])
        assert (cli.trainer.progress_bar_callback is not None) is bar

    def test_checkpointing_off_is_the_reason(self, tmp_path, capsys):
        argv = ["dpa", "--max-epochs", "1", "--out", str(tmp_path), "-q",
                "--trainer.enable_checkpointing", "false", "--trainer.limit_val_batches", "0",
                *TINY["dpa"]]  # fmt: skip
        assert train_main(argv) == 0
        out = capsys.readouterr().out
        assert "checkpoint: none (checkpointing off: --trainer.enable_checkpointing false)" in out
        assert not list(tmp_path.rglob("*.ckpt"))


class TestCommand:
    def test_without_the_extra(self, monkeypatch, capsys):
        import importlib.util

        from hocnet.cli import main

        real = importlib.util.find_spec
        monkeypatch.setattr(
            importlib.util,
            "find_spec",
            lambda name, *a: None if name == "jsonargparse" else real(name, *a),
        )
        assert main(["train", "dpa"]) == 2
        err = capsys.readouterr().err
        assert "pip install -e '.[learn]'" in err and "jsonargparse" in err
        assert main(["train", "--help"]) == 0  # the usage needs no extra
        assert "hocnet train dpa --help" in capsys.readouterr().out

    def test_bad_value_is_one_line(self, capsys):
        from hocnet.cli import main

        assert main(["train", "dpa", "--model.tau_end", "0"]) == 2
        err = capsys.readouterr().err
        assert (
            err == "hocnet: error: train: --model.tau_end: expected a number in (0, inf), got 0\n"
        )
