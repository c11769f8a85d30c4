"""Package discovery for setuptools (the rest of the metadata is in pyproject.toml).

Every package under ``gausstac_maniskill/`` is found automatically. ``agents/``, ``tasks/`` and
``assets/`` sit at the top of the repository and install as ``gausstac_maniskill.agents``,
``.tasks`` and ``.assets``, the assets as package data.
"""
from setuptools import find_packages, setup

MAPPED = ("agents", "tasks", "assets")  # top-level folders installed inside the package

packages = find_packages(include=["gausstac_maniskill", "gausstac_maniskill.*"])
package_dir = {}
for folder in MAPPED:
    for sub in [""] + [f".{p}" for p in find_packages(where=folder)]:
        packages.append(f"gausstac_maniskill.{folder}{sub}")
        package_dir[f"gausstac_maniskill.{folder}{sub}"] = folder + sub.replace(".", "/")

setup(
    packages=packages,
    package_dir=package_dir,
    include_package_data=False,
    package_data={"gausstac_maniskill.assets": ["*/*.ply", "*/*.json", "*/*.obj", "*/*.stl", "*/*.glb",
                                                "*/*.urdf", "*/*.png"]},
)
