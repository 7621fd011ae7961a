"""calbench.bench.scenario: campaign files (TOML): their types, their parser, their time line."""
