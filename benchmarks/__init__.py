"""Speed measurements of jaxanom against its peers (PyTorch, scikit-learn); see RESULTS.md."""
