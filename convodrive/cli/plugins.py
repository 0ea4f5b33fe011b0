"""``convodrive plugins [NAME]``: every generator and backend found through entry points, or one
plugin's options (type, range, default, help) as its ``Options`` dataclass declares them."""

from __future__ import annotations

import argparse
import difflib

from convodrive.plugins import BACKEND_GROUP, GENERATOR_GROUP, list_plugins, load_plugin, plugin_names
from convodrive.plugins.option_help import describe_options
from convodrive.plumbing.errors import UserError

GROUPS = (("generators", GENERATOR_GROUP), ("backends", BACKEND_GROUP))


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "plugins",
        help="list generators and backends, or one plugin's options",
        description="List every installed generator and backend plugin; with NAME, that plugin's options.",
    )
    p.add_argument("name", nargs="?", metavar="NAME", help="a generator or backend: list its options")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.name:
        print(plugin_help(args.name))
        return 0
    for title, group in GROUPS:
        print(f"{title}:")
        for info in list_plugins(group):
            if info.available:
                print(f"  {info.name:<12} {info.description}")
            else:
                print(f"  {info.name:<12} (unavailable: {info.problem})")
    print("`convodrive plugins NAME` lists a plugin's options.")
    return 0


def plugin_help(name: str) -> str:
    """What a plugin is and every option it takes, with how to set them."""
    for _, group in GROUPS:
        if name in plugin_names(group):
            cls = load_plugin(group, name)
            break
    else:
        known = [n for _, g in GROUPS for n in plugin_names(g)]
        close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
        hint = f"did you mean '{close[0]}'?" if close else f"installed: {', '.join(sorted(known))}"
        raise UserError(f"unknown plugin '{name}' ({hint})")
    generator = group == GENERATOR_GROUP
    kind = "generator" if generator else "backend"
    lines = [f"{kind} {name}: {cls.description}"]
    infos = describe_options(cls.Options)
    if not infos:
        lines.append("It takes no options.")
        return "\n".join(lines)
    how = (
        f"-G KEY=VALUE, or generator: {{{name}: {{KEY: VALUE}}}} in a --config YAML"
        if generator
        else f"-B {name}.KEY=VALUE, or backends: {{{name}: {{KEY: VALUE}}}} in a --config YAML or robot profile"
    )
    lines.append(f"options ({how}):")
    width = max(len(i.name) for i in infos) + 2
    for info in infos:
        default = "required" if info.required else f"default {info.default_text()}"
        lines.append(f"  {info.name:<{width}}{info.kind()}; {default}")
        lines.append(f"  {'':<{width}}{info.help}")
    return "\n".join(lines)


def options_markdown() -> str:
    """The README's table of every built-in plugin's options (scripts/readme_options.py writes it)."""
    out = []
    for title, group in GROUPS:
        for name in plugin_names(group):
            try:
                cls = load_plugin(group, name)
            except UserError:
                continue
            if not cls.__module__.startswith("convodrive."):
                continue  # third-party plugins document themselves
            infos = describe_options(cls.Options)
            kind = title[:-1]
            out.append(f"**{name}** ({kind}{'' if infos else ', no options'})")
            out.append("")
            if infos:
                out.append("| option | type | default | what it does |")
                out.append("|---|---|---|---|")
                for info in infos:
                    default = "required" if info.required else f"`{info.default_text()}`"
                    out.append(f"| `{info.name}` | {info.kind()} | {default} | {info.help} |")
                out.append("")
    return "\n".join(out).rstrip() + "\n"
