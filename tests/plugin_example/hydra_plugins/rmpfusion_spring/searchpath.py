"""Adds the plugin's YAML presets to every Hydra app's search path, so rmpfusion's config groups
(rmp/, tree/) gain the plugin's options without rmpfusion knowing about the plugin."""

from hydra.core.config_search_path import ConfigSearchPath
from hydra.plugins.search_path_plugin import SearchPathPlugin


class RmpfusionSpringSearchPath(SearchPathPlugin):
    def manipulate_search_path(self, search_path: ConfigSearchPath) -> None:
        search_path.append(provider="rmpfusion-spring", path="pkg://rmpfusion_spring/conf")
