"""The shipped weak forms (the repository's forms/, installed as the package fempm.forms)."""
