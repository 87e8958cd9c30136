"""KyberCore's database: the engine and its migrations."""
