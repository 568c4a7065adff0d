"""`hippo-nav config`: the default pipeline config as JSON, a config file checked without running, or a
config file resolved (every default filled in)."""

from __future__ import annotations

import argparse
import json

HELP = "print the default config as JSON, check a config file without running, or show it resolved"
DESCRIPTION = (
    "--defaults prints every section of the pipeline config with its defaults (the registered parts' "
    "sections included) as JSON: save it, edit what you need (or keep only what you change: the rest take "
    "their defaults) and give it to `hippo-nav run --config`. --check FILE reads and validates a config "
    "file as `run --config` does, without running: `FILE: valid` (an old spelling still reads, with a "
    "warning on stderr naming today's), or the one error line naming the field, exit 2. --show FILE prints "
    "FILE's resolved config, as a run writes it into config.json; --preset NAME a preset's (`\"preset\": "
    "\"paper\"` in a file lays the paper's settings under the file's own); --check reads the vocabulary file a "
    "config names too. What depends on the input (output.state_frames against the frames) is checked when a "
    "run starts (docs/pipeline.md)."
)


def add_arguments(config: argparse.ArgumentParser) -> None:
    from hippo_nav.system.presets import PRESETS

    what = config.add_argument_group("one of").add_mutually_exclusive_group(required=True)
    what.add_argument(
        "--defaults",
        action="store_true",
        help="print the full default config as JSON (e.g. hippo-nav config --defaults > my.json)",
    )
    what.add_argument(
        "--check",
        metavar="FILE",
        help="validate a config file as run --config reads it (fields left out: their defaults), without "
        "running: 'FILE: valid', or the error and exit 2",
    )
    what.add_argument(
        "--preset",
        metavar="NAME",
        choices=list(PRESETS),
        help="print a preset's resolved config as JSON (paper: the system as the paper describes it; "
        "docs/pipeline.md, Presets)",
    )
    what.add_argument(
        "--show",
        metavar="FILE",
        help="print a config file's resolved config as JSON (every default filled in)",
    )


def command(args: argparse.Namespace) -> int:
    from hippo_nav.system.config import PipelineConfig, load_config, resolved_config_dict

    if args.check is not None:
        checked = load_config(args.check)  # raises the one-line error (exit 2); old spellings are warnings
        from hippo_nav.view_cells.words import Vocabulary, WordViewConfig

        words = checked.section("view_words")
        if isinstance(words, WordViewConfig) and words.vocabulary is not None:  # read as a run would
            Vocabulary.load(words.vocabulary)
        print(f"{args.check}: valid")
        return 0
    # The same JSON a run writes into its config.json: it loads back with --config to the same config.
    if args.preset is not None:
        config = load_config(None, args.preset)
    else:
        config = PipelineConfig() if args.defaults else load_config(args.show)
    print(json.dumps(resolved_config_dict(config), indent=2))
    return 0
