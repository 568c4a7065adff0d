"""The space of a sweep: axes given on the command line or in a sweep file, expanded into runs with stable ids.

Axes (each a list of values; a run takes one value of every axis, the runs are their cross-product):
- `set`: config overrides, `key = [v1, v2]` with `key` a dotted path into the config (`views.novelty_threshold`,
  `lesions.dorsal`); `--set key=v1,v2` on the command line, every value parsed as JSON where it is JSON
  (`true`, `0.4`, `null`, `[0, 10]`) and kept as text otherwise (`RatSlam`). A single value sets every run.
- `seeds`: the config's `seed`, `0-4`, `0,3,7` or a list.
- `lesion`: lesion conditions, each `none` or module names joined by `+` (`ventral+dorsal`), applied as
  `hippo-nav run --lesion` is (`PipelineConfig.with_lesions`, added to the config's `lesions` section).
- `sequence`: sequences of the dataset (as `run --sequence`).
- `odometry`: `vo` (the built-in stereo VO), `drift` (the run's ground truth made to drift like a real
  odometry, `hippo_nav.synthetic.drifting_odometry`, replayed) or a trajectory file replayed as with
  `run --odometry FILE` (in a sweep file a table `{file = "…", align = "start", format = "kitti"}`).

A sweep file (TOML or YAML) holds the dataset flags of `run` (`dataset`, `dataset_kind`, `start`, `stop`,
`stride`, and the loader options the loaders declare in `FLAGS`), a base config (`config_file =
"base.json"` and/or a `[config]` table of sections, which wins), the default results folder (`out`), and
the axes: at the top level for one cross-product, or in `[[space]]` tables for a union of cross-products
(axes left out of a table take the top-level ones). Relative paths are taken from the current folder and
written into the manifests as absolute paths.

A run's id is a readable slug of its axis values and 8 hex digits of the SHA-256 of everything that makes the
run (dataset, range, sequence, odometry, lesion, seed, overrides), so the same space always gives the same ids
and a rerun finds its earlier runs (resume); two runs differing in any value never share an id. An override's
value is taken as the validated config holds it (`1` for a float field is `1.0`), and two runs with the same
resolved config, dataset, sequence and odometry are one run (two spellings of one setting run once).

Limits, checked before anything is expanded: at most `MAX_RUNS` runs in a sweep (the size of every
cross-product is computed from the lengths of its axes, a seed range from its ends), a sweep file of at most
`MAX_SWEEP_FILE_BYTES`, values nested at most `MAX_NESTING` deep. Every problem is a one-line `HippoNavError`
naming the file, the axis or the key.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import os
import re
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hippo_nav._core import HippoNavError
from hippo_nav._defaults import dotted, merged
from hippo_nav.io import read_text
from hippo_nav.system.config import PipelineConfig, config_from_dict, load_config, resolved_config_dict

MAX_SEED = 2**31 - 1
"""Seeds reach OpenCV's RNG, which takes a 32-bit signed integer."""
MAX_RUNS = 10_000
"""Runs in one sweep at most. Validating a run's config takes about 0.6 ms, so this many take seconds; more
is most likely a typo (a seed range of 10**12), and a study that big is better split into several sweeps."""
MAX_FRAME = 10**9
"""A sweep file's frame numbers and stride at most (as `run`'s flags): more is a typo of extra digits."""
MAX_SWEEP_FILE_BYTES = 2**20
"""A sweep file is a few kB; a bigger one is refused before it is read."""
MAX_NESTING = 32
"""Lists and tables in a sweep file (or a `--set` value) nested at most this deep (a config is 3 deep)."""
VALIDATION_NOTICE_RUNS = 2_000
"""From this many runs on, validating their configs (seconds) is said before it starts."""
LESION_MODULES = ("ventral", "intermediate", "dorsal")
AXES = ("set", "seeds", "lesion", "sequence", "odometry")
"""The axes a sweep file or the command line may give."""
SLUG_MAX_CHARS = 72
_KEY = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$")


def loader_option_keys() -> tuple[str, ...]:
    """The loader options a sweep passes on: the keywords of every registered loader's `FLAGS` (the flags
    of `hippo-nav run` and `hippo-nav sweep`), in registry order."""
    from hippo_nav.datasets import LOADERS

    keys = (flag.keyword for loader in LOADERS.values() for flag in loader.FLAGS)
    return tuple(dict.fromkeys(keys))


def dataset_keys() -> tuple[str, ...]:
    """The dataset flags of `run` a sweep file or the command line may give."""
    return ("dataset", "dataset_kind", "start", "stop", "stride", *loader_option_keys())


def file_keys() -> set[str]:
    """The keys a sweep file may hold."""
    return {*AXES, *dataset_keys(), "config", "config_file", "out", "space"}


@dataclass(frozen=True)
class Odometry:
    """One value of the odometry axis: `vo`, `drift`, or a trajectory `file` (absolute) replayed."""

    kind: str  # "vo", "drift" or "file"
    file: str | None = None
    file_format: str | None = None
    align: str | None = None

    @property
    def label(self) -> str:
        if self.kind != "file":
            return self.kind
        assert self.file is not None
        return Path(self.file).stem + (f"@{self.align}" if self.align else "")

    def as_dict(self) -> dict[str, Any]:
        if self.kind != "file":
            return {"kind": self.kind}
        return {"kind": "file", "file": self.file, "format": self.file_format, "align": self.align}


@dataclass(frozen=True)
class DatasetInput:
    """The dataset flags every run of a sweep shares (`run`'s; `path` None: the built-in demo loop)."""

    path: str | None = None
    kind: str | None = None
    start: int | None = None
    stop: int | None = None
    stride: int = 1
    options: tuple[tuple[str, str], ...] = ()

    def as_dict(self) -> dict[str, Any]:
        return {
            "path": self.path, "kind": self.kind, "start": self.start, "stop": self.stop,
            "stride": self.stride, "options": dict(self.options),
        }  # fmt: skip


@dataclass(frozen=True)
class Block:
    """One cross-product: every combination of its axes' values."""

    overrides: dict[str, list[Any]] = field(default_factory=dict)
    seeds: list[int] | None = None
    lesions: list[str] = field(default_factory=lambda: ["none"])
    sequences: list[str | None] = field(default_factory=lambda: [None])
    odometries: list[Odometry] = field(default_factory=lambda: [Odometry("vo")])

    def size(self) -> int:
        n = len(self.seeds or [None]) * len(self.lesions) * len(self.sequences) * len(self.odometries)
        for values in self.overrides.values():
            n *= len(values)
        return n


@dataclass(frozen=True)
class RunSpec:
    """One run of a sweep: its id, what it varies, and its validated config (as the dict it came from)."""

    run_id: str
    dataset: DatasetInput
    sequence: str | None
    odometry: Odometry
    lesion: str
    seed: int | None
    overrides: dict[str, Any]
    config: dict[str, Any]  # the base config with the overrides, lesions and seed applied (validated)

    def axes(self) -> dict[str, Any]:
        """What this run varies, flat: the columns of a report."""
        out: dict[str, Any] = {
            "sequence": self.sequence,
            "odometry": self.odometry.label,
            "lesion": self.lesion,
        }
        out.update(self.overrides)
        out["seed"] = self.seed
        return out

    def pipeline_config(self) -> PipelineConfig:
        config = config_from_dict(self.config, f"run {self.run_id}")
        return config.with_lesions(*lesion_modules(self.lesion))


@dataclass
class SweepSpace:
    """The whole space: the shared dataset flags and base config, and one or more cross-products."""

    dataset: DatasetInput = field(default_factory=DatasetInput)
    base_config: dict[str, Any] = field(default_factory=dict)
    base_config_file: str | None = None
    blocks: list[Block] = field(default_factory=lambda: [Block()])
    out: str | None = None

    def size(self) -> int:
        """How many runs the cross-products make (duplicates counted), from the lengths of the axes alone."""
        return sum(block.size() for block in self.blocks)

    def runs(self, echo: Callable[[str], None] | None = None) -> list[RunSpec]:
        """Every run, in the order of the blocks and their axes, each once (the same resolved config,
        dataset, sequence and odometry: one run, whatever the spelling); every config is validated here,
        before anything runs. The size is checked before anything is expanded (`MAX_RUNS`); `echo` is told
        when the validation will take a while."""
        total = check_size(self.size())
        if echo is not None and total >= VALIDATION_NOTICE_RUNS:
            echo(f"validating the configs of {total} runs (about {max(1, round(total * 0.0006))} s)…")
        runs: dict[str, RunSpec] = {}
        seen: set[str] = set()
        cache: dict[str, _Validated] = {}
        for block in self.blocks:
            for identity, spec in _expand(block, self.dataset, self.base_config, cache):
                # A set and a dict: duplicates are found by hashing, in time linear in the runs.
                if identity not in seen:
                    seen.add(identity)
                    runs.setdefault(spec.run_id, spec)
        return list(runs.values())

    def as_dict(self) -> dict[str, Any]:
        return {
            "dataset": self.dataset.as_dict(),
            "base_config_file": self.base_config_file,
            "base_config": self.base_config,
            "blocks": [
                {
                    "set": block.overrides,
                    "seeds": block.seeds,
                    "lesion": block.lesions,
                    "sequence": block.sequences,
                    "odometry": [o.as_dict() for o in block.odometries],
                }
                for block in self.blocks
            ],
        }


# ------------------------------------------------------------------------------------------------
# Parsing values


def split_values(text: str) -> list[str]:
    """`a,b,[1,2],"x,y"` → `['a', 'b', '[1,2]', '"x,y"']`: commas inside brackets, braces or quotes stay."""
    parts: list[str] = []
    current: list[str] = []
    depth, quote = 0, ""
    for char in text:
        if quote:
            quote = "" if char == quote else quote
        elif char in "\"'":
            quote = char
        elif char in "[{":
            depth += 1
        elif char in "]}":
            depth -= 1
        elif char == "," and depth == 0:
            parts.append("".join(current).strip())
            current = []
            continue
        current.append(char)
    parts.append("".join(current).strip())
    return parts


def parse_value(text: str) -> Any:
    """A command-line value: JSON where it parses (`true`, `0.4`, `null`, `[0, 10]`, `"x"`), else the text
    (also an integer of more digits than Python reads); nested deeper than `MAX_NESTING` is refused."""
    try:
        value = json.loads(text)
    except RecursionError:
        raise HippoNavError(
            f"value {_shown(text)}: nested too deeply (at most {MAX_NESTING} levels of [ ] and {{ }})"
        ) from None
    except ValueError:  # not JSON (json.JSONDecodeError), or an integer of over 4 300 digits
        return text
    check_structure(value, f"value {_shown(text)}")
    return value


def _shown(value: Any, limit: int = 40) -> str:
    """`value` as a message quotes it: cut to `limit` characters, so a pasted megabyte stays one short line."""
    try:
        text = repr(value)
    except ValueError:  # an integer of over 4 300 digits
        return "(a number of thousands of digits)"
    return text if len(text) <= limit else text[:limit] + f"… ({len(text)} characters)"


MAX_VALUES = 100_000
"""Values (every list item and table entry, nested ones too) in a sweep file at most. YAML's aliases can make a
file of a few lines hold billions of values by reference; counting stops at this many."""


def check_structure(value: Any, where: str) -> None:
    """Refuse values nested deeper than `MAX_NESTING` or holding more than `MAX_VALUES` values, before any
    recursive code (validation, copying, hashing) meets them. Iterative: it cannot overflow the stack."""
    stack, count = [(value, 0)], 0
    while stack:
        node, depth = stack.pop()
        count += 1
        if depth > MAX_NESTING:
            raise HippoNavError(
                f"{where}: nested too deeply (at most {MAX_NESTING} levels of lists and tables)"
            )
        if count > MAX_VALUES:
            raise HippoNavError(f"{where}: holds more than {MAX_VALUES} values; a sweep file is a few lines")
        if isinstance(node, dict):
            stack.extend((v, depth + 1) for v in node.values())
        elif isinstance(node, (list, tuple)):
            stack.extend((v, depth + 1) for v in node)


def check_size(total: int) -> int:
    """`total` runs, or the one-line error of a sweep bigger than `MAX_RUNS` (checked before expanding)."""
    if total > MAX_RUNS:
        raise HippoNavError(
            f"the sweep would make {total} runs; a sweep makes at most {MAX_RUNS}: check the axes for a typo "
            "(a seed range such as 0-1000000), or split the study into several sweeps"
        )
    return total


def parse_set(text: str) -> tuple[str, list[Any]]:
    """`--set key=v1,v2` → (key, [v1, v2])."""
    key, sep, values = text.partition("=")
    key = key.strip()
    if not sep or not values.strip():
        raise HippoNavError(
            f"--set {text}: give KEY=VALUE[,VALUE…], e.g. --set views.novelty_threshold=0.4,0.45"
        )
    return _checked_key(key, f"--set {text if len(text) <= 80 else _shown(text, 80)}"), [
        parse_value(v) for v in split_values(values)
    ]


def parse_seeds(spec: str | int | Sequence[Any]) -> list[int]:
    """`0-4`, `0,3,7`, `0-2,10`, an integer, or a list of integers → the seeds, in order, each once. The
    ranges are checked (each end from 0 to `MAX_SEED`, at most `MAX_RUNS` seeds in all) from their ends,
    before any is expanded: a typo such as `0-1000000000000` is one line, not gigabytes of seeds."""
    shown = _shown(spec)
    if isinstance(spec, bool) or not isinstance(spec, (str, int, list, tuple)):
        raise HippoNavError(f"seeds {shown}: give integers or ranges, e.g. 0-4 or 0,3,7")
    ranges: list[tuple[int, int]] = []
    if isinstance(spec, str):
        for part in (p.strip() for p in spec.split(",")):
            lo, dash, hi = part.partition("-")
            try:
                ranges.append((int(lo), int(hi)) if dash else (int(part), int(part)))
            except ValueError:  # also a number of over 4 300 digits
                raise HippoNavError(f"seeds {shown}: give integers or ranges, e.g. 0-4 or 0,3,7") from None
    else:
        for seed in [spec] if isinstance(spec, int) else spec:
            if isinstance(seed, bool) or not isinstance(seed, int):
                raise HippoNavError(f"seed {_shown(seed)}: give integers from 0 to {MAX_SEED}")
            ranges.append((seed, seed))
    for first, last in ranges:
        for end in (first, last):
            if not 0 <= end <= MAX_SEED:
                raise HippoNavError(f"seed {_shown(end)}: give integers from 0 to {MAX_SEED}")
        if last < first:
            raise HippoNavError(
                f"seeds {first}-{last}: the range is empty; give the lower seed first ({last}-{first})"
            )
    count = sum(last - first + 1 for first, last in ranges)
    if count > MAX_RUNS:
        raise HippoNavError(
            f"seeds {shown}: {count} seeds, and a sweep makes at most {MAX_RUNS} runs; check the range for a typo"
        )
    # dict.fromkeys: in order, each once, in time linear in the seeds.
    seeds = list(dict.fromkeys(itertools.chain.from_iterable(range(a, b + 1) for a, b in ranges)))
    if not seeds:
        raise HippoNavError(f"seeds {shown}: no seed given (e.g. 0-4)")
    return seeds


def lesion_modules(condition: str) -> list[str]:
    """`none` → []; `ventral+dorsal` → ["ventral", "dorsal"] (checked)."""
    if condition == "none":
        return []
    names = [n.strip() for n in condition.split("+")]
    unknown = [n for n in names if n not in LESION_MODULES]
    if unknown or not names:
        raise HippoNavError(
            f"lesion {_shown(condition)}: give none or module names joined by +, from {', '.join(LESION_MODULES)}"
        )
    return names


def _checked_lesion(condition: Any) -> str:
    if not isinstance(condition, str):
        raise HippoNavError(
            f"lesion {_shown(condition)}: give a name (none, ventral, intermediate, dorsal, a+b)"
        )
    modules = lesion_modules(condition.strip())
    # One spelling per condition, so `dorsal+ventral` and `ventral+dorsal` are the same run.
    return "+".join(m for m in LESION_MODULES if m in modules) or "none"


def parse_odometry(value: Any, file_format: str | None = None, align: str | None = None) -> Odometry:
    """`vo`, `drift`, a path, or (in a file) `{file, format, align}`; a path must exist."""
    from hippo_nav.vo.replay import ALIGNMENTS, FORMATS

    if isinstance(value, dict):
        unknown = set(value) - {"file", "format", "align"}
        if unknown or "file" not in value:
            raise HippoNavError(f"odometry {_shown(value)}: a table takes file (required), format and align")
        file_format, align, value = value.get("format", file_format), value.get("align", align), value["file"]
    if not isinstance(value, str) or not value.strip():
        raise HippoNavError(f"odometry {_shown(value)}: give vo, drift or a trajectory file")
    if value in ("vo", "drift"):
        return Odometry(value)
    if file_format is not None and (not isinstance(file_format, str) or file_format not in FORMATS):
        raise HippoNavError(
            f"odometry {_shown(value)}: format {_shown(file_format)}; choose from {', '.join(FORMATS)}"
        )
    if align is not None and (not isinstance(align, str) or align not in ALIGNMENTS):
        raise HippoNavError(
            f"odometry {_shown(value)}: align {_shown(align)}; choose from {', '.join(ALIGNMENTS)}"
        )
    path = _absolute(value, f"odometry {_shown(value)}")
    assert path is not None
    if not _is(Path(path), "file"):
        raise HippoNavError(f"odometry {_shown(value)}: no such file (give vo, drift or a trajectory file)")
    return Odometry("file", path, file_format, align)


def _checked_key(key: str, where: str) -> str:
    if not _KEY.match(key):
        raise HippoNavError(
            f"{where}: {_shown(key)} is not a dotted config key such as views.novelty_threshold"
        )
    if key == "seed":
        raise HippoNavError(
            f"{where}: the seed is its own axis; give --seeds 0-4 (or seeds = [...] in a file)"
        )
    if key.startswith("engine.lesioned"):
        raise HippoNavError(f"{where}: set lesions with lesions.NAME or the lesion axis, not engine.lesioned")
    return key


# ------------------------------------------------------------------------------------------------
# Expansion


def apply_override(config: dict[str, Any], key: str, value: Any) -> None:
    """`config["a"]["b"] = value` for `key = "a.b"`, creating the sections on the way."""
    *sections, last = key.split(".")
    node = config
    for i, name in enumerate(sections):
        child = node.setdefault(name, {})
        if not isinstance(child, dict):
            raise HippoNavError(
                f"--set {key}: {'.'.join(sections[: i + 1])} is a value, not a config section"
            )
        node = child
    node[last] = value


def _slug_value(value: Any) -> str:
    text = value if isinstance(value, str) else json.dumps(value, separators=(",", ""), default=str)
    return re.sub(r"[^A-Za-z0-9.+-]+", "", text.replace(",", "+").replace(" ", ""))[:24] or "x"


def run_id(facts: dict[str, Any]) -> str:
    """Readable slug of the axis values + 8 hex digits of the SHA-256 of every fact of the run."""
    parts = []
    if facts["sequence"] is not None:
        parts.append(f"seq{_slug_value(facts['sequence'])}")
    parts.append(_slug_value(facts["odometry"]["kind"] if facts["odometry"]["kind"] != "file" else
                             Path(facts["odometry"]["file"]).stem))  # fmt: skip
    if facts["lesion"] != "none":
        parts.append(f"no-{facts['lesion']}")
    for key, value in facts["overrides"].items():
        parts.append(f"{key.rsplit('.', 1)[-1]}={_slug_value(value)}")
    if facts["seed"] is not None:
        parts.append(f"s{facts['seed']}")
    slug = "_".join(parts)[:SLUG_MAX_CHARS].strip("_.")
    digest = hashlib.sha256(json.dumps(facts, sort_keys=True, default=str).encode()).hexdigest()[:8]
    return f"{slug}-{digest}"


@dataclass(frozen=True)
class _Validated:
    """A run's config once validated: its values flat (dotted keys, as the config resolves them) and the hash
    of the resolved config with each lesion condition applied (computed when first asked)."""

    config: PipelineConfig
    flat: dict[str, Any]
    hashes: dict[str, str] = field(default_factory=dict)

    def identity_hash(self, lesion: str) -> str:
        if lesion not in self.hashes:
            self.hashes[lesion] = config_hash(self.config.with_lesions(*lesion_modules(lesion)))
        return self.hashes[lesion]


def _expand(
    block: Block, dataset: DatasetInput, base: dict[str, Any], cache: dict[str, _Validated]
) -> Iterator[tuple[str, RunSpec]]:
    """(identity, run) for every combination of the block's axes. The identity is the hash of what the run
    does (dataset, sequence, odometry, resolved config), so two spellings of one setting are one run."""
    keys = sorted(block.overrides)
    seeds: list[int | None] = list(block.seeds) if block.seeds else [None]
    data = dataset.as_dict()
    # The base config names its runs too: a second sweep with another one into the same folder makes runs of
    # its own beside the first's instead of replacing them. What it outputs (`output`: figures, recordings)
    # changes no result, and a base config of nothing else keeps the ids it always had.
    settings = {section: value for section, value in base.items() if section != "output"}
    base_sha256 = hashlib.sha256(json.dumps(settings, sort_keys=True, default=str).encode()).hexdigest()
    for values in itertools.product(
        block.sequences, block.odometries, block.lesions, *(block.overrides[k] for k in keys),
        seeds,
    ):  # fmt: skip
        sequence, odometry, lesion, *chosen, seed = values
        given = dict(zip(keys, chosen, strict=True))
        config = copy.deepcopy(base)
        for key, value in given.items():
            apply_override(config, key, value)
        if seed is not None:
            config["seed"] = seed
        text = json.dumps(config, sort_keys=True, default=str)
        validated = cache.get(text)
        if validated is None:
            described = ", ".join(f"{k}={json.dumps(v, default=str)[:60]}" for k, v in given.items())
            described += f"{', ' if described else ''}seed {seed}" if seed is not None else ""
            # The errors of --config, before any run.
            checked = config_from_dict(config, f"run ({described or 'the base config'})")
            validated = cache[text] = _Validated(checked, dotted(resolved_config_dict(checked)))
        # Each value as the validated config holds it (1 for a float field is 1.0): one id per setting.
        overrides = {k: validated.flat.get(k, v) for k, v in given.items()}
        facts = {
            "dataset": data, "sequence": sequence, "odometry": odometry.as_dict(),
            "lesion": lesion, "seed": seed, "overrides": overrides,
        }  # fmt: skip
        if settings:
            facts["base_config_sha256"] = base_sha256
        spec = RunSpec(run_id(facts), dataset, sequence, odometry, lesion, seed, overrides, config)
        identity = json.dumps(
            [data, sequence, odometry.as_dict(), validated.identity_hash(lesion)], sort_keys=True, default=str
        )
        yield identity, spec


def config_hash(config: PipelineConfig) -> str:
    """SHA-256 of the fully resolved config (every default filled in): equal hashes, equal settings."""
    text = json.dumps(resolved_config_dict(config), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


# ------------------------------------------------------------------------------------------------
# Building a space from the command line and a sweep file


def read_sweep_file(path: str | Path) -> dict[str, Any]:
    """A sweep file's table: TOML (`.toml`) or YAML (`.yaml`, `.yml`)."""
    path = Path(path)
    if path.suffix not in (".toml", ".yaml", ".yml"):
        raise HippoNavError(f"{path}: a sweep file ends in .toml, .yaml or .yml")
    try:
        text = read_text(path, "sweep file", MAX_SWEEP_FILE_BYTES)
    except HippoNavError:
        raise  # too big, or not UTF-8: the message names the file
    except (OSError, ValueError) as err:  # ValueError: a NUL byte in the name
        raise HippoNavError(f"{path}: cannot read the sweep file ({_os_reason(err)})") from None
    if path.suffix == ".toml":
        data = parse_toml(text, path)
    else:
        data = parse_yaml(text, path)
    check_structure(data, str(path))  # first: YAML's aliases can make a few lines hold billions of values
    keys = file_keys()
    if not isinstance(data, dict):
        raise HippoNavError(f"{path}: a sweep file holds one table of keys ({', '.join(sorted(keys))})")
    unknown = sorted(_shown(k) if not isinstance(k, str) else k for k in data if k not in keys)
    if unknown:
        raise HippoNavError(
            f"{path}: unknown keys {_shown(unknown, 200)}; a sweep file takes {', '.join(sorted(keys))}"
        )
    return data


def parse_toml(text: str, path: Path) -> Any:
    """The table of a TOML sweep file, or a one-line error naming the file."""
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # the sweep extra installs tomli on Python 3.10
        import tomli as tomllib
    try:
        return tomllib.loads(text)
    except RecursionError:
        raise HippoNavError(f"{path}: nested too deeply (at most {MAX_NESTING} levels)") from None
    except ValueError as err:  # TOMLDecodeError, or a number Python cannot read
        raise HippoNavError(f"{path}: not valid TOML ({' '.join(str(err).split())[:200]})") from None


def parse_yaml(text: str, path: Path) -> Any:
    """The mapping of a YAML sweep file, or a one-line error naming the file."""
    import yaml

    from hippo_nav.datasets.common import strict_yaml_loader

    try:
        # A key given twice is an error: YAML would keep the last, and the sweep run what was not meant.
        return yaml.load(text, Loader=strict_yaml_loader())  # a SafeLoader subclass: no arbitrary objects
    except RecursionError:
        raise HippoNavError(f"{path}: nested too deeply (at most {MAX_NESTING} levels)") from None
    except yaml.YAMLError as err:
        raise HippoNavError(f"{path}: not valid YAML ({str(err).splitlines()[0]})") from None
    except (ValueError, TypeError, OverflowError) as err:  # a date or number the constructors cannot make
        raise HippoNavError(
            f"{path}: not valid YAML ({type(err).__name__}: {_shown(str(err), 200)})"
        ) from None


def _os_reason(err: BaseException) -> str:
    """What failed, in words (an `OSError`'s text without its `[Errno N]` and repeated file name)."""
    if isinstance(err, OSError):
        return (err.strerror or type(err).__name__).lower()
    return str(err)


def _as_list(value: Any) -> list[Any]:
    return list(value) if isinstance(value, list) else [value]


def _block_from(table: dict[str, Any], where: str, defaults: Block, odometry_flags: dict[str, Any]) -> Block:
    unknown = sorted(str(k) for k in table if k not in AXES)
    if unknown:
        raise HippoNavError(f"{where}: unknown axes {_shown(unknown, 200)}; choose from {', '.join(AXES)}")
    # An axis with no values would make a sweep of no runs: refused, naming the axis.
    for axis in AXES:
        if axis in table and table[axis] in ([], "", {}):
            raise HippoNavError(
                f"{where}: the {axis} axis has no values; give at least one (or leave it out)"
            )
    overrides = dict(defaults.overrides)
    if "set" in table:
        if not isinstance(table["set"], dict):
            raise HippoNavError(f'{where}: set is a table of "key" = [values]')
        for key, values in dotted(table["set"]).items():
            checked = _checked_key(str(key), f"{where}, set")
            if values == [] or values == {}:
                raise HippoNavError(
                    f"{where}: set {checked} has no values; give at least one (or leave it out)"
                )
            overrides[checked] = _as_list(values)
    seeds = parse_seeds(table["seeds"]) if "seeds" in table else defaults.seeds
    lesions = (
        list(dict.fromkeys(_checked_lesion(v) for v in _as_list(table["lesion"])))
        if "lesion" in table
        else defaults.lesions
    )
    sequences: list[str | None] = (
        list(dict.fromkeys(_checked_sequence(v) for v in _as_list(table["sequence"])))
        if "sequence" in table
        else defaults.sequences
    )
    odometries = (
        list(dict.fromkeys(parse_odometry(v, **odometry_flags) for v in _as_list(table["odometry"])))
        if "odometry" in table
        else defaults.odometries
    )
    return Block(overrides, seeds, lesions, sequences, odometries)


def _checked_sequence(value: Any) -> str:
    """A sequence name: text (or a number, as YAML reads `05`… as 5: give it quoted) that is not blank."""
    if isinstance(value, bool) or not isinstance(value, (str, int)) or not str(value).strip():
        raise HippoNavError(f'sequence {_shown(value)}: give a sequence name, e.g. 00 or "05"')
    return str(value).strip()


def build_space(
    file: str | Path | None = None,
    *,
    sets: Sequence[str] = (),
    seeds: str | None = None,
    lesions: str | None = None,
    sequences: str | None = None,
    odometries: str | None = None,
    odometry_format: str | None = None,
    odometry_align: str | None = None,
    config: str | None = None,
    dataset: dict[str, Any] | None = None,
    no_figures: bool = False,
) -> SweepSpace:
    """The space of `hippo-nav sweep`: the file's (if any), with the command line's axes replacing the file's
    axes of the same name in every cross-product and its dataset flags (`dataset`: the keys of
    `dataset_keys()` that were given) replacing the file's. `no_figures`: the base config without figures."""
    data = read_sweep_file(file) if file is not None else {}
    odometry_flags = {"file_format": odometry_format, "align": odometry_align}
    given = {k: v for k, v in (dataset or {}).items() if v is not None}
    flags = {k: data[k] for k in dataset_keys() if k in data} | given
    dataset_input = _dataset_input(flags)
    swept = sequences is not None or "sequence" in data or any("sequence" in b for b in _space_tables(data))
    if swept and dataset_input.path is None:
        raise HippoNavError(
            "the sequence axis needs a dataset (--dataset PATH); without one the demo loop runs"
        )
    base_file = _absolute(config if config is not None else data.get("config_file"), "config_file")
    base: dict[str, Any] = {}
    if base_file is not None:
        try:
            load_config(base_file)  # the errors of `run --config`
        except RecursionError:
            raise HippoNavError(f"{base_file}: nested too deeply (at most {MAX_NESTING} levels)") from None
        try:
            base = json.loads(read_text(base_file, "config file"))
        except (OSError, RecursionError) as err:
            raise HippoNavError(f"{base_file}: cannot read the config file ({_os_reason(err)})") from None
        check_structure(base, base_file)
    inline = data.get("config")
    if inline is not None:
        if not isinstance(inline, dict):
            raise HippoNavError(
                f"{file}: config is a table of config sections (config_file: a JSON file's path)"
            )
        base = merged(base, inline)
        config_from_dict(base, f"{file}: [config]")
    if no_figures:
        base = merged(base, {"output": {"figures": False}})

    command_line: dict[str, Any] = {}
    if sets:
        command_line["set"] = dict(parse_set(s) for s in sets)
    if seeds is not None:
        command_line["seeds"] = seeds
    if lesions is not None:
        command_line["lesion"] = split_values(lesions)
    if sequences is not None:
        command_line["sequence"] = split_values(sequences)
    if odometries is not None:
        command_line["odometry"] = split_values(odometries)

    top = _block_from({k: data[k] for k in AXES if k in data}, str(file), Block(), odometry_flags)
    tables = _space_tables(data) or [{}]
    blocks = []
    for i, table in enumerate(tables):
        where = f"{file}, space {i + 1}"
        block = _block_from(table, where, top, odometry_flags)
        blocks.append(_block_from(command_line, "command line", block, odometry_flags))
    out = data.get("out")
    if out is not None and (not isinstance(out, str) or not out.strip()):
        raise HippoNavError(f"{file}: out {_shown(out)}: give the sweep folder's path as text")
    space = SweepSpace(dataset_input, base, base_file, blocks, out)
    check_size(space.size())  # from the axes' lengths, before a single run is expanded
    return space


def _space_tables(data: dict[str, Any]) -> list[dict[str, Any]]:
    tables = data.get("space", [])
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise HippoNavError("space: give a list of tables ([[space]] in TOML, a list of mappings in YAML)")
    return tables


def _absolute(path: Any, what: str = "path") -> str | None:
    """A path from the command line or a sweep file as an absolute path (`$VARS` and `~` expanded), or a
    one-line error naming `what` (a path that is not text, holds a NUL byte or loops through links)."""
    if path is None:
        return None
    if not isinstance(path, str) or not path.strip() or "\0" in path:
        raise HippoNavError(f"{what} {_shown(path)}: give a file or folder path as text")
    try:
        return str(Path(os.path.expandvars(path)).expanduser().resolve())
    except (OSError, RuntimeError) as err:  # RuntimeError: a loop of symbolic links
        raise HippoNavError(f"{what} {_shown(path)}: cannot resolve the path ({_os_reason(err)})") from None


def _is(path: Path, kind: str) -> bool:
    """Whether `path` is an existing file ("file") or anything ("any"); False where it cannot be looked at
    (a name too long, no permission), as for a missing one."""
    try:
        return path.is_file() if kind == "file" else path.exists()
    except (OSError, ValueError):
        return False


FRAME_BOUNDS = {"start": (0, MAX_FRAME - 1), "stop": (1, MAX_FRAME), "stride": (1, MAX_FRAME)}
"""The range of each frame flag (as `run --start/--stop/--stride`)."""


def _dataset_input(flags: dict[str, Any]) -> DatasetInput:
    from hippo_nav.datasets import LOADERS

    path = _absolute(flags.get("dataset"), "dataset")
    if path is not None and not _is(Path(path), "any"):
        raise HippoNavError(f"dataset {_shown(flags['dataset'])}: no such file or folder")
    kind = flags.get("dataset_kind")
    if kind is not None and (not isinstance(kind, str) or kind not in LOADERS):
        raise HippoNavError(f"dataset_kind {_shown(kind)}: choose from {', '.join(LOADERS)}")
    options = {}
    for key in loader_option_keys():
        value = flags.get(key)
        if value is None:
            continue
        if not isinstance(value, (str, int, float)) or isinstance(value, bool):
            raise HippoNavError(f"{key} {_shown(value)}: give it as text, as on the command line")
        options[key] = str(value)
    if "topics" in options:
        options["topics"] = str(_absolute(options["topics"], "topics"))
    if path is None and (kind is not None or options):
        raise HippoNavError("dataset_kind and loader options need a dataset (--dataset PATH)")
    numbers = {}
    for name, (lo, hi) in FRAME_BOUNDS.items():
        value = flags.get(name)
        if value is not None and (
            isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi
        ):
            raise HippoNavError(f"{name} {_shown(value)}: give an integer frame number from {lo} to {hi}")
        numbers[name] = value
    if numbers["start"] is not None and numbers["stop"] is not None and numbers["stop"] <= numbers["start"]:
        raise HippoNavError(
            f"stop {numbers['stop']} is not after start {numbers['start']}: no frame would run (stop is the frame "
            "to stop before)"
        )
    stride = numbers["stride"] if numbers["stride"] is not None else 1
    return DatasetInput(path, kind, numbers["start"], numbers["stop"], stride, tuple(sorted(options.items())))
