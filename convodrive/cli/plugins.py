"""``convodrive plugins``: every generator and backend found through entry points."""

from __future__ import annotations

import argparse

from convodrive.plugins import BACKEND_GROUP, GENERATOR_GROUP, list_plugins


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "plugins", help="list generators and backends", description="List every installed generator and backend plugin."
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    for title, group in (("generators", GENERATOR_GROUP), ("backends", BACKEND_GROUP)):
        print(f"{title}:")
        for info in list_plugins(group):
            if info.available:
                print(f"  {info.name:<12} {info.description}")
            else:
                print(f"  {info.name:<12} (unavailable: {info.problem})")
    return 0
