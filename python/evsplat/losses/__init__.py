"""The paper's losses, one module per family: event (L_e), flow (L_ef), patch (L_m), depth
(L_d), reg (L_ne, L_sp), and the SSIM they share with evaluation."""
