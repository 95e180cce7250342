"""SymPy derivations of the angular observation equations and their code generation."""
