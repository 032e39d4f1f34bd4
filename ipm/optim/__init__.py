"""Search algorithms over generator parameters (ask/tell or pure update functions)."""
