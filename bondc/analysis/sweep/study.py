"""A sweep's file as a study: the csv journal that rows are appended to as points finish, what the
study was computed from (``<table>.csv.study``), and the points a resumed sweep finds there."""

from __future__ import annotations

import csv
import io
import json
import os
from pathlib import Path
from typing import Mapping, Sequence

from bondc.analysis.sweep.grid import _usage
from bondc.analysis.sweep.metrics import MOTOR_RULES
from bondc.analysis.sweep.table import STATUSES, SweepPoint
from bondc.errors import UsageError
from bondc.pipeline import file_texts
from bondc import codes


def _key(parameters: Mapping, names: Sequence[str]) -> tuple:
    """A point's identity in a results file: its varied parameters' SI values (12 digits)."""
    return tuple(f"{float(parameters[name]):.12g}" for name in names)


def _not_resumable(path, why: str) -> UsageError:
    return _usage(codes.E970, f"cannot resume from '{path}': {why}",
                  hint="it is not the table of this sweep, and bondc leaves it as it is; write to another file "
                       "(-o), or delete it to start again")


def _previous_points(path, result_header: list[str], axes, metrics, motors: bool) -> dict[tuple, SweepPoint]:
    """The points an earlier run of the same sweep wrote to ``path`` (a .csv or .json), by key.

    A file of another sweep (other columns), or one that bondc did not write (a row it would not
    write, a json that is not a sweep's), is not resumed: E970 says so rather than mixing them or
    replacing the file. A csv row cut short (an interruption) is not a point: that point runs again."""
    path = Path(path)
    if not path.exists() or path.stat().st_size == 0:
        return {}
    names = [axis.name for axis in axes]
    found: dict[tuple, SweepPoint] = {}
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(path.read_text(encoding="utf-8"))
            if not isinstance(data, dict) or not isinstance(data.get("points", []), list):
                raise ValueError("not the json table of a sweep")
            if [p["name"] for p in data.get("parameters", [])] != names or \
                    [m["name"] for m in data.get("metrics", [])] != [m.name for m in metrics]:
                raise ValueError("other columns")
            for item in data.get("points", []):
                point = SweepPoint(int(item["index"]), tuple(item["values"]), item["status"], item.get("message"),
                                   item.get("path"), dict(item["parameters"]),
                                   {k: _from_json_number(v) for k, v in (item.get("metrics") or {}).items()},
                                   item.get("t_reached"), wall_time=item.get("wall_time"),
                                   motors=tuple(item["motors"]) if "motors" in item else None)
                if point.status not in STATUSES:
                    raise ValueError(f"a point with the status {point.status!r}")
                found[_key(point.parameters, names)] = point
            return found
        with open(path, newline="", encoding="utf-8") as handle:
            rows = list(csv.reader(handle))
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, AttributeError, csv.Error) as error:
        raise _not_resumable(path, str(error) or type(error).__name__) from None
    if not rows:
        return {}
    if rows[0] != result_header:
        raise _usage(codes.E970, f"'{path}' holds the table of another sweep (other columns)",
                     hint="bondc leaves it as it is; write to another file (-o), or delete it to start again")
    width = len(result_header)
    columns = {name: number for number, name in enumerate(result_header)}
    for line, row in enumerate(rows[1:], 2):
        if len(row) < width:
            continue            # a row cut short by an interruption: that point runs again
        if len(row) > width or row[columns["status"]] not in STATUSES or not row[0].isdigit():
            raise _not_resumable(path, f"row {line} is not a row bondc writes")
        try:
            parameters = {axis.name: float(row[1 + i]) for i, axis in enumerate(axes)}
        except ValueError:
            continue            # a row without its values (written by an older bondc): that point runs again
        try:
            metrics_values = {m.name: _from_csv(row[1 + len(axes) + i]) for i, m in enumerate(metrics)}
            wall_time = _from_csv(row[columns["wall_time [s]"]])
        except ValueError:
            raise _not_resumable(path, f"row {line} is not a row bondc writes") from None
        status = row[columns["status"]]
        point = SweepPoint(int(row[0]), (), status, row[columns["message"]] or None, None, parameters,
                           metrics_values if status in ("ok", "incomplete") else {},
                           wall_time=wall_time,
                           motors=tuple(m for m in row[columns["motors"]].split(";") if m) if motors else None)
        found[_key(parameters, names)] = point
    return found


def _check_grid(output, previous: dict[tuple, SweepPoint], keys: Sequence[tuple], axes, samples, seed) -> None:
    """E970 where ``output`` holds finished points that are not points of this sweep: running it
    would rewrite the table without them. A grid that holds every one of them resumes or extends
    the study."""
    grid = set(keys)
    strays = [point for key, point in previous.items() if key not in grid]
    if not strays:
        return
    example = ", ".join(f"{name}={value:.6g}" for name, value in strays[0].parameters.items())
    how = ("the same --samples, --range and --seed" if samples else "the same --vary values, or a grid that "
           "holds them,")
    hint = (f"bondc leaves '{output}' as it is. To resume it give {how} as the run that wrote it; otherwise "
            "write to another file (-o), or delete it to start again")
    if samples and seed is None:
        hint += " (a Latin hypercube without --seed draws other points every run: give --seed)"
    raise _usage(codes.E970, f"'{output}' holds {len(strays)} finished point{'s' if len(strays) != 1 else ''} "
                         f"that {'are' if len(strays) != 1 else 'is'} not in this sweep (e.g. {example}): "
                         "running it would drop them", hint=hint)


def _study(graph, model, experiment, sets, t_end, dt, motors, inertia_ratio=None) -> dict:
    """What the points of a sweep were computed from besides their own values: the text of every
    file the model read, the model and experiment chosen, the --set values, t_end, dt and the motor
    catalogue. A resumed sweep keeps the points of an earlier run only where these are the same."""
    import hashlib

    texts = sorted(file_texts(graph).items())
    digest = lambda data: hashlib.sha256(data).hexdigest()      # noqa: E731
    catalogue = None
    if motors is not None:
        try:
            catalogue = digest(Path(motors).read_bytes())
        except OSError:
            catalogue = str(motors)
    study = {"model files": digest(json.dumps(texts).encode("utf-8")), "model": model, "experiment": experiment,
             "--set": [item if isinstance(item, str) else getattr(getattr(item, "source", None), "text", repr(item))
                       for item in sets or ()],
             "t_end": t_end, "dt": dt, "motor catalogue": catalogue}
    if motors is not None:
        # the motors column depends on the sizing rules and the inertia-ratio limit: a study made
        # with other rules (before the inertia ratio was one) is not resumed with these
        study["motor rules"] = MOTOR_RULES
        study["--inertia-ratio"] = inertia_ratio
    return study


def study_file(output) -> Path:
    """Beside a sweep's csv table, what its points were computed from (:func:`_study`): ``x.csv.study``."""
    return Path(str(output) + ".study")


def _described(graph, path, experiment, axes, shown_units, converters, metrics) -> dict:
    """What a study's report shows that its csv does not hold: the model's name and file, the
    experiment, and the unit each varied parameter and metric is shown in (``shown = (si - offset) /
    factor``; a metric's is its output's declared unit, ``P_kPa.min`` in kPa). Not part of the study's
    identity: a resume does not compare it."""
    parameters = []
    for axis, unit, converter in zip(axes, shown_units, converters):
        offset = float(converter.to_si(0.0))
        parameters.append({"name": axis.name, "unit": unit, "factor": float(converter.to_si(1.0)) - offset,
                           "offset": offset})
    return {"model name": graph.name, "model file": str(path),
            "experiment": experiment.name if experiment is not None else None,
            "parameters": parameters,
            "metrics": [{"name": m.name, "si_unit": m.si_unit, "unit": m.unit, "factor": m.display_factor}
                        for m in metrics]}


def _write_study(output, study: dict, described: dict | None = None) -> None:
    """The record of ``study`` beside the csv; ``described`` under "report" (see :func:`_described`)."""
    from bondc.io import atomic_write_text

    record = dict(study)
    if described is not None:
        record["report"] = described
    atomic_write_text(study_file(output), json.dumps(record, indent=1) + "\n")


def _check_study(output, study: dict) -> None:
    """E970 where the points in ``output`` were computed from another model or other options
    (a table written without the record of its study is resumed as before)."""
    path = Path(output)
    try:
        if path.suffix.lower() == ".json":
            recorded = json.loads(path.read_text(encoding="utf-8")).get("settings", {}).get("study")
        else:
            recorded = json.loads(study_file(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, AttributeError):
        recorded = None
    if not isinstance(recorded, dict):
        return
    labels = {"model files": "a different text of the model file or its imports", "model": "another --model",
              "experiment": "another --experiment", "--set": "other --set values", "t_end": "another t_end",
              "dt": "another dt", "motor catalogue": "another motor catalogue"}
    changed = [labels.get(key, key) for key in study if json.dumps(recorded.get(key)) != json.dumps(study[key])]
    if changed:
        raise _usage(codes.E970, f"'{output}' holds points of this sweep computed with {', '.join(changed)}: "
                             "resuming would mix them with points of this one",
                     hint="write to another file, or delete it to start again")


def _from_csv(text: str) -> float | None:
    return None if text == "" else float(text)


def _from_json_number(value):
    return float(value) if isinstance(value, str) else value


class _Journal:
    """The csv results file, one row appended and flushed as each point finishes, so that nothing
    finished is lost whatever stops the sweep; at the end the file is rewritten in grid order.

    A file that exists is only appended to (its header and rows were checked by
    :func:`_previous_points` and :func:`_check_grid`): a new file, or an empty one, gets the header."""

    def __init__(self, path, header: list[str]):
        self.path = Path(path)
        fresh = not self.path.exists() or self.path.stat().st_size == 0
        if fresh:
            from bondc.io import atomic_write_text

            buffer = io.StringIO()
            csv.writer(buffer, lineterminator="\n").writerow(header)
            atomic_write_text(self.path, buffer.getvalue())
        self.handle = open(self.path, "a", newline="", encoding="utf-8")
        if not fresh:
            self._end_line()
        self.writer = csv.writer(self.handle, lineterminator="\n")

    def _end_line(self) -> None:
        """A row an interruption cut short stays a separate (ignored) line."""
        with open(self.path, "rb") as check:
            check.seek(0, os.SEEK_END)
            if check.tell():
                check.seek(-1, os.SEEK_END)
                if check.read(1) != b"\n":
                    self.handle.write("\n")

    def add(self, row: list) -> None:
        self.writer.writerow(row)
        self.handle.flush()
        os.fsync(self.handle.fileno())

    def close(self) -> None:
        self.handle.close()
