"""The installed package's version, as every output that says what made it reports it
(the torque node's config, bag_torques' config)."""

from importlib import metadata


def package_version() -> str:
    try:
        return metadata.version("forearm_dynamics")
    except metadata.PackageNotFoundError:
        return "unknown"
