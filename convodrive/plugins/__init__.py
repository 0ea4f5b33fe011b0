"""Plugins: discovery through entry points, and the options each plugin declares."""

from convodrive.plugins.registry import (
    BACKEND_GROUP,
    GENERATOR_GROUP,
    PluginInfo,
    list_plugins,
    load_plugin,
    missing_modules,
    plugin_kind,
    plugin_names,
    unknown_plugin,
)

__all__ = [
    "BACKEND_GROUP",
    "GENERATOR_GROUP",
    "PluginInfo",
    "list_plugins",
    "load_plugin",
    "missing_modules",
    "plugin_kind",
    "plugin_names",
    "unknown_plugin",
]
