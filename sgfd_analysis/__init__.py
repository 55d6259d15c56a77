"""The SGFD paper's research analysis on top of the zoo: the correlation study (section 5.3, Fig. 4) and the
interpretability figures (appendix C: saliency maps, weighted samples, the classifier's accuracy)."""
