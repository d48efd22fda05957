//! Every built-in indenter (the paper's 18 plus `paralines`) renders: a finite, non-empty image
//! that shows a contact, on both shipped sensors.

use hardware_mocks::sim::optics::{ImageEffects, background, geometric_field, render};
use rig_core::config::{ElastomerConfig, RigConfig};
use rig_core::indenter::Indenter;

#[test]
fn all_indenters_render_a_visible_contact_on_both_sensors() {
    let names = Indenter::list_builtin();
    assert_eq!(names.len(), 19, "{names:?}");
    let elastomer = ElastomerConfig::default();
    let mut optics = RigConfig::sim_source().optics.unwrap();
    // A quarter-size image keeps the debug-build test quick; the geometry is the same.
    optics = optics.with_resolution(160, 120);
    let mut target = RigConfig::sim_target().optics.unwrap();
    target = target.with_resolution(160, 120);
    let fx = ImageEffects::realistic();
    for name in names {
        let indenter = Indenter::builtin(name).unwrap();
        let field = geometric_field(&indenter, &elastomer, [0.0, 0.0], 0.5, [0.3, 0.2], 0.1);
        for o in [&optics, &target] {
            let img = render(o, &fx, &field, 3);
            assert_eq!(img.dimensions(), (160, 120));
            let bg = background(o, &fx, 3);
            let changed = img
                .pixels()
                .zip(bg.pixels())
                .filter(|(p, q)| (0..3).any(|k| p.0[k].abs_diff(q.0[k]) > 12))
                .count();
            assert!(
                changed > 100,
                "{name}: only {changed} pixels show the contact"
            );
        }
    }
}
