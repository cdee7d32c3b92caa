"""The command line's option conversion without pydantic (georef_cli.coercion) against typer's own, and the
console script's exit (georef_cli.main.main: os._exit once the command is done)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import typer.main
from georef_cli import coercion
from georef_cli.main import app
from typer._click import Context
from typer._click.exceptions import BadParameter
from typer._coercion import build_runtime_param

GEOREF = Path(sys.executable).parent / "georef"
DATA = Path(__file__).resolve().parents[2] / "data"

#: raw command-line values of every kind, plain and not: each converted both ways must agree
STRINGS = ["", "-", "abc", "a b", "1", "007", "-0", "+3", "-12", "1.5", ".5", "1.", "-0.0", "1e3", "1E-2", "1e400",
           "-1e400", "1_000", " 2 ", "nan", "inf", "0x10", "\u0661", "ekf", "EKF", "Rts", "graph", "bogus", "ground",
           "AIR", "kf", "mekf", "true", "false", "mems-ivru", "x.kml", "metashape:ms.csv"]


def _commands():
    group = typer.main.get_command(app)
    ctx = Context(group, info_name="georef")
    yield group, ctx
    for name in group.list_commands(ctx):
        command = group.get_command(ctx, name)
        yield command, Context(command, info_name=name, parent=ctx)


def _outcome(runtime, value, param, ctx):
    try:
        result = runtime._coerce_value(value, param, ctx)
    except BadParameter as exc:
        return "BadParameter", exc.format_message()
    return type(result), repr(result)  # repr: nan equals nan


def test_plain_conversion_agrees_with_typer_for_every_parameter(tmp_path):
    """For every parameter of every command and the group, each raw value converts to the same value of the same
    type, or fails with the same message, through the plain conversion and through typer's pydantic one."""
    existing = tmp_path / "file.txt"
    existing.write_text("x")
    values = [*STRINGS, str(existing), str(tmp_path), str(tmp_path / "missing.txt"), True, False, 3, 2.5, None]
    checked = 0
    for command, ctx in _commands():
        params = command.get_params(ctx)
        coercion.install(params)
        for param in params:
            plain = param._runtime_param
            if not isinstance(plain, coercion.PlainRuntimeParam):
                continue
            reference = build_runtime_param(param.type_descriptor)
            many = param.multiple or param.nargs == -1
            samples = [[v] for v in values] + [values[:3], ()] if many else values
            for value in samples:
                assert _outcome(plain, value, param, ctx) == _outcome(reference, value, param, ctx), \
                    (command.name, param.name, value)
                checked += 1
    assert checked > 2000


def test_every_parameter_of_georef_process_gets_the_plain_conversion():
    group = typer.main.get_command(app)
    ctx = Context(group, info_name="georef")
    command = group.get_command(ctx, "process")
    sub = Context(command, info_name="process", parent=ctx)
    assert isinstance(command, coercion.PlainCoercionCommand) and isinstance(group, coercion.PlainCoercionGroup)
    params = command.get_params(sub)
    coercion.install(params)
    assert coercion.AVAILABLE, "typer's internals changed: georef_cli.coercion falls back to pydantic throughout"
    assert all(isinstance(p._runtime_param, coercion.PlainRuntimeParam) for p in params), \
        [p.name for p in params if not isinstance(p._runtime_param, coercion.PlainRuntimeParam)]


def test_parsing_georef_process_does_not_import_pydantic():
    code = (
        "import sys\n"
        "import typer.main\n"
        "from georef_cli.main import app\n"
        "group = typer.main.get_command(app)\n"
        f"args = ['process', {str(DATA / 'POS.txt')!r}, {str(DATA / 'Kamera.txt')!r}, '--config', "
        f"{str(DATA / 'flight.toml')!r}, '-o', 'eo.csv', '-q', '--method', 'EKF', '--gnss-rate', '1', "
        "'--export', 'odm:geo.txt', '--vehicle', 'air']\n"
        "ctx = group.make_context('georef', list(args))\n"
        "command = group.get_command(ctx, 'process')\n"
        "sub = command.make_context('process', args[1:], parent=ctx)\n"
        "assert sub.params['method'].value == 'ekf' and sub.params['gnss_rate'] == 1.0, sub.params\n"
        "print('pydantic' in sys.modules)\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "False"


def test_a_wrong_choice_keeps_typers_message(tmp_path):
    run = subprocess.run([str(GEOREF), "process", "--method", "bogus", str(DATA / "POS.txt"), str(DATA / "Kamera.txt")],
                         capture_output=True, text=True, timeout=60, check=False, cwd=tmp_path)
    assert run.returncode == 2
    assert "Invalid value for '--method'" in run.stderr and "'bogus' is not one of 'rts', 'ekf'" in run.stderr


@pytest.mark.parametrize(("args", "code", "stream", "text"), [
    (["--version"], 0, "stdout", "georef "),
    (["process", "missing-POS.txt", "missing-Kamera.txt", "-q"], 2, "stderr", "missing-POS.txt"),
    (["info", str(DATA / "POS.txt")], 0, "stdout", "POS.txt"),
])
def test_the_console_script_exits_with_the_commands_code_and_output(tmp_path, args, code, stream, text):
    """The console entry point ends with os._exit: the exit code and everything printed still arrive."""
    run = subprocess.run([str(GEOREF), *args], capture_output=True, text=True, timeout=120, check=False, cwd=tmp_path)
    assert run.returncode == code, run.stderr
    assert text in getattr(run, stream)
