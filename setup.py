"""Package layout beside pyproject.toml (which holds the metadata): the bmctl package, and the
shipped model cards and controller settings, which sit beside the package in a clone and travel
inside it in a wheel as ``bmctl/_shipped/models`` and ``bmctl/_shipped/controllers`` (read by
``bmctl.shipped.shipped_dir``)."""

from setuptools import find_packages, setup

SHIPPED = {f"bmctl._shipped.{folder}": folder for folder in ("models", "controllers")}

setup(packages=find_packages(include=["bmctl", "bmctl.*"]) + list(SHIPPED),
      package_dir=SHIPPED,
      package_data={name: ["*.toml"] for name in SHIPPED})
