"""The packaged fits (``fit-*.toml``), their data (``data/*.csv``) and the script that
makes the data (:mod:`.generate`)."""
