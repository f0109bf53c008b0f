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

    def test_usage_without_system(self, capsys):
        assert train_main([]) == 0
        assert "dpa" in capsys.readouterr().out
        assert train_main(["svm"]) == 2
        assert "svm" in capsys.readouterr().err

    def test_bad_values_name_the_argument(self):
        with pytest.raises(ConfigError, match="`lr`"):
            build_cli("dpa", ["--model.lr", "-1"])
        with pytest.raises(ConfigError, match="`matrices`"):
            build_cli("dpa", ["--model.matrices", "diagonal"])
        with pytest.raises(ConfigError, match="speed"):
            build_cli("hoc", ["--data.speed", "0.1", "3.0"])
        with pytest.raises(SystemExit):  # jsonargparse: 'Parser key "model.lr"'
            build_cli("dpa", ["--model.lr", "abc"])

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

    def test_bad_value_is_one_line(self, capsys):
        from hocnet.cli import main

        assert main(["train", "dpa", "--model.tau_end", "0"]) == 2
        lines = [x for x in capsys.readouterr().err.splitlines() if x.startswith("hocnet:")]
        assert lines == [lines[0]] and "`tau_end`" in lines[0]
