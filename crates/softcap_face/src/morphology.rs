//! Binary morphology and connected components on pixel masks (thesis §4.3.1: "morphological
//! operations (e.g., erosion and dilation) to remove possible pixel classification errors").
//!
//! Masks are row-major `width × height`; a mask shorter than that is a caller bug and panics
//! (the sizes come from the same image, never from a file).

/// Erode with a (2r+1)² square: a pixel stays set iff its whole neighbourhood is set
/// (outside the image counts as set, so borders do not eat the mask).
pub fn erode(mask: &[bool], width: usize, height: usize, r: usize) -> Vec<bool> {
    window(mask, width, height, r, true)
}

/// Dilate with a (2r+1)² square: a pixel is set iff any neighbour is set.
pub fn dilate(mask: &[bool], width: usize, height: usize, r: usize) -> Vec<bool> {
    window(mask, width, height, r, false)
}

fn window(mask: &[bool], width: usize, height: usize, r: usize, all: bool) -> Vec<bool> {
    let mut out = vec![false; mask.len()];
    if width == 0 || height == 0 {
        return out;
    }
    for y in 0..height {
        for x in 0..width {
            let mut acc = all;
            'outer: for yy in y.saturating_sub(r)..=(y + r).min(height - 1) {
                for xx in x.saturating_sub(r)..=(x + r).min(width - 1) {
                    let v = mask[yy * width + xx];
                    if all && !v {
                        acc = false;
                        break 'outer;
                    }
                    if !all && v {
                        acc = true;
                        break 'outer;
                    }
                }
            }
            out[y * width + x] = acc;
        }
    }
    out
}

/// Opening (erode, then dilate): removes isolated false positives.
pub fn open(mask: &[bool], width: usize, height: usize, r: usize) -> Vec<bool> {
    dilate(&erode(mask, width, height, r), width, height, r)
}

/// Closing (dilate, then erode): fills isolated false negatives.
pub fn close(mask: &[bool], width: usize, height: usize, r: usize) -> Vec<bool> {
    erode(&dilate(mask, width, height, r), width, height, r)
}

/// 4-connected components of the set pixels, largest first (ties by first pixel index), each
/// as sorted pixel indices.
pub fn connected_components(mask: &[bool], width: usize, height: usize) -> Vec<Vec<usize>> {
    let mut label = vec![usize::MAX; mask.len()];
    let mut comps: Vec<Vec<usize>> = Vec::new();
    for start in 0..mask.len() {
        if !mask[start] || label[start] != usize::MAX {
            continue;
        }
        let id = comps.len();
        let mut stack = vec![start];
        label[start] = id;
        let mut pixels = Vec::new();
        while let Some(i) = stack.pop() {
            pixels.push(i);
            let (x, y) = (i % width, i / width);
            let mut push = |j: usize| {
                if mask[j] && label[j] == usize::MAX {
                    label[j] = id;
                    stack.push(j);
                }
            };
            if x > 0 {
                push(i - 1);
            }
            if x + 1 < width {
                push(i + 1);
            }
            if y > 0 {
                push(i - width);
            }
            if y + 1 < height {
                push(i + width);
            }
        }
        pixels.sort_unstable();
        comps.push(pixels);
    }
    comps.sort_by(|a, b| b.len().cmp(&a.len()).then(a[0].cmp(&b[0])));
    comps
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn opening_removes_speckle_and_keeps_blocks() {
        let (w, h) = (12, 10);
        let mut m = vec![false; w * h];
        for y in 2..7 {
            for x in 3..9 {
                m[y * w + x] = true;
            }
        }
        m[9 * w] = true; // speckle
        let o = open(&m, w, h, 1);
        assert!(!o[9 * w]);
        assert_eq!(o.iter().filter(|&&v| v).count(), 30);
        let mut holed = m.clone();
        holed[4 * w + 5] = false;
        assert!(close(&holed, w, h, 1)[4 * w + 5]);
        let comps = connected_components(&m, w, h);
        assert_eq!(comps.len(), 2);
        assert_eq!(comps[0].len(), 30);
    }
}
