"""Scenes shipped with mlsim: TOML files (``mlsim check scenes/mavig_default.toml``), one folder per study or sensor kind."""
