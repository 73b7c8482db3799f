"""Reading and writing: descriptions, sessions, exports."""
