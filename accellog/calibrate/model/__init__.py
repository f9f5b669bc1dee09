"""The effect library, model composition, the least-squares fit and honest parameter uncertainties."""
